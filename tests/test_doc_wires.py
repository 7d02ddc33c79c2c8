"""The documents' peer and daemon lines, run as written (read through tests/doc_blocks.py, with
what tests/doc_claims.toml declares: the wire's address made the test's own, private endpoints,
limits a loaded machine keeps): each simulated device up, the daemon pointed at it serving, the
arm enabled and held through the wire with nothing tripped. README.md's own wire lines, which
also move the arm, are tests/test_readme_wires.py's."""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time

import pytest

from bench.wires import listening
from daemon.client.client import Client
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.ports import free_tcp_port
from tests import doc_blocks, doc_runs
from tests.daemons import endpoint_env, private_endpoints, wait_for_own_daemon
from tests.doc_blocks import BIN, ROOT
from tests.test_readme_tour import options
from tests.wirehelpers import as_device, private_bus

pytestmark = pytest.mark.slow(seconds=60)

HOLD_S = 3.0  # [s] enabled through the wire before the checks


def fills(tmp_path) -> dict:
    """The values the declared substitutions ask for: a link, ports and a CAN bus of the test's,
    its endpoints and recordings."""
    group, bus_port = private_bus()
    eps = private_endpoints(tmp_path)
    return {"link": str(tmp_path / "bridge"), "port": str(free_tcp_port()), "rtu_port": str(free_tcp_port()),
            "group": group, "bus_port": str(bus_port), "recordings": str(tmp_path / "rec"),
            "endpoints": options(eps), "eps": eps}


def ready_check(peer: doc_blocks.Command, values: dict):
    """What tells that ``peer``'s device is up: its link, or its port listening (a CAN node on
    a multicast group has nothing to wait for)."""
    if values["link"] in peer.text:
        return lambda: os.path.exists(values["link"])
    port = re.search(r"--port (\d+)", peer.text)
    if port and "can_peer" not in peer.text:
        return lambda: listening(int(port.group(1)))
    return lambda: True


def run_pair(peer: doc_blocks.Command, daemon_line: str, values: dict, cwd, hold_s: float = HOLD_S,
             move=None) -> dict:
    """The peer's line, then the daemon's (as it runs: a line's ``text``), the arm enabled (and
    ``move(client, env)`` run) and held ``hold_s`` from the enable; the daemon's status at the
    end. Both stopped on the way out."""
    proc = subprocess.Popen(["bash", "-c", "exec " + peer.text], cwd=cwd, stdout=subprocess.DEVNULL,
                            preexec_fn=as_device)
    daemon = None
    try:
        ready, deadline = ready_check(peer, values), time.monotonic() + 60
        while not ready():
            assert proc.poll() is None and time.monotonic() < deadline, f"the peer did not come up: {peer.text}"
            time.sleep(0.1)
        daemon = subprocess.Popen(["bash", "-c", "exec " + daemon_line], cwd=cwd)
        eps = values["eps"]
        env = endpoint_env(eps)
        with Client(**eps, timeout=5.0) as client:
            wait_for_own_daemon(client, daemon)
            done = subprocess.run([BIN + "pneumactl", "enable"], env=env, capture_output=True, text=True, timeout=60)
            assert done.returncode == 0, (daemon_line, done.stderr, client.status()["cause"])
            enabled_at = time.monotonic()
            if move is not None:
                move(client, env)
            time.sleep(max(0.0, enabled_at + hold_s - time.monotonic()))
            status = client.status()
            # as one string: pytest shortens a tuple's dicts, and the counters tell a silent wire
            # (no replies) from one whose replies were refused (unexpected_seq, tx_dropped)
            assert status["state"] == "enabled" and status["trips"] == 0, \
                f"{daemon_line}: {status['cause']}; {status['transport']}"
            assert status["transport"]["reads"] > 100 * hold_s, status["transport"]
            return status
    finally:
        if daemon is not None:
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(STOP_WAIT_S)
        proc.send_signal(signal.SIGTERM)
        proc.wait(STOP_WAIT_S)


def pair_up(commands: list[doc_blocks.Command]) -> list[tuple[doc_blocks.Command, doc_blocks.Command]]:
    """A section's (peer, daemon) pairs: each daemon with the peer whose address it names."""
    peers = [c for c in commands if " -m sim_backend." in c.text]
    daemons = [c for c in commands if re.search(r"(^|/)pneumad ", c.text)]
    pairs = []
    for daemon_line in daemons:
        peer = next(p for p in peers if _address(p) in daemon_line.text)
        pairs.append((peer, daemon_line))
    assert len(pairs) == len(daemons) and {id(p) for p, _ in pairs} == {id(p) for p in peers}, commands
    return pairs


def _address(peer: doc_blocks.Command) -> str:
    """What a daemon line names of the device ``peer`` serves: its link, port or group."""
    found = re.search(r"--(?:link|channel) (\S+)|--port (\d+)", peer.text)
    return found.group(1) or found.group(2)


SECTIONS = [
    ("docs/transports.md", 'Modbus TCP and RTU (`backend = "modbus"`)'),
    ("docs/transports.md", 'CAN (`backend = "can"`)'),
    ("docs/muscle-rig.md", "Behind a real wire"),
    ("docs/rigs.md", "The axis behind a real wire"),
]


@pytest.mark.parametrize("doc, section", SECTIONS)
def test_a_documents_peer_and_daemon_lines_run(doc, section, tmp_path):
    values = fills(tmp_path)
    for peer, daemon_line in pair_up(doc_blocks.commands(doc, section, **values)):
        status = run_pair(peer, daemon_line.text, values, tmp_path)
        assert status["transport"]["errors"] == 0, (daemon_line.written, status["transport"])


def test_the_serial_bridges_host_build_lines_run(tmp_path):
    """``make`` in a scratch directory holding a copy of the firmware (the line's relative
    paths: nothing is built in the checkout), the firmware on its plant, the daemon on it."""
    values = fills(tmp_path)
    work = tmp_path / "work"
    shutil.copytree(ROOT / "firmware" / "serial-bridge", work / "firmware" / "serial-bridge",
                    ignore=shutil.ignore_patterns("build"))
    build, plant, daemon_line = doc_blocks.commands(
        "docs/serial-bridge.md", "The host build: the same core, driven by the real daemon", **values)
    if not (shutil.which("gcc") and shutil.which("make")):
        pytest.skip("the firmware's host build needs gcc and make (.ci/run installs them)")
    done = doc_runs.run(build, work, timeout=300)
    assert done.returncode == 0, done.explain()
    status = run_pair(plant, daemon_line.text, values, work)
    assert status["transport"]["errors"] == 0, status["transport"]


def test_the_simulated_bridges_synopsis_runs(tmp_path):
    """The synopsis with its optional parts given (tests/doc_claims.toml), and a daemon of the
    test's on its link (the section shows no daemon line): the corrupted replies counted, the
    arm still held."""
    values = fills(tmp_path)
    peer, = doc_blocks.commands("docs/serial-bridge.md", "The simulated bridge", **values)
    ours = (f"{BIN}pneumad --no-rt --transport serial --transport-option port={values['link']} "
            f"--safety stale_after_s=1.0 --safety stall_after_s=5.0 --transport-option open_timeout_s=30 "
            f"--record-dir {values['recordings']} {values['endpoints']}")
    status = run_pair(peer, ours, values, tmp_path)
    assert status["transport"]["counters"]["crc_errors"] > 0, status["transport"]
