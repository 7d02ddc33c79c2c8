"""README.md's "Reaching the rig through a real wire" lines, run as written: each peer, the
daemon pointed at it, the arm enabled and moved, and the daemon still enabled 10 s after the
enable with nothing tripped.

What a test must change in them: the wire's address (a link under the test's directory, a
free port, a multicast group of its own: the README's are a lab PC's), the daemon's endpoints
(private, reached through the environment), and the machine's load: the lines' 50 ms stale
limit is a quiet PC's, and this suite runs beside other work (two CPU hogs held a wire's peer
for over a second), so the daemon is given the limits the other wire tests use (1 s stale, the
tolerant stall of tests.daemons). What is checked is that the lines work, not this machine's
latency (`pneumad latency`, bench.transport_cost measure that)."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import time

import pytest

from bench.wires import listening
from daemon.client.client import Client
from daemon.testing.ports import free_tcp_port
from tests.daemons import endpoint_env, private_endpoints, wait_for_own_daemon
from tests.test_readme_tour import BIN, ROOT
from tests.wirehelpers import as_device, private_bus

pytestmark = pytest.mark.slow(seconds=20)
LOADED = ["--safety", "stale_after_s=1.0", "--safety", "stall_after_s=5.0"]  # after the line's own: these win
WIRE_LOADED = {"modbus": ["--transport-option", "timeout_s=1.0"]}  # a transaction, waited for as the Modbus tests do


def wire_pairs() -> list[tuple[str, str]]:
    """(peer line, daemon line) per wire, continuations joined, comments dropped."""
    section = (ROOT / "README.md").read_text().split("## Reaching the rig through a real wire", 1)[1].split("\n## ")[0]
    joined = re.sub(r"\\[ \t]*\n\s*", " ", section)
    lines = [re.sub(r"\s+#.*$", "", line.strip()).replace(".venv/bin/", BIN, 1) for line in joined.splitlines()
             if line.strip().startswith(".venv/bin/")]
    peers = [line for line in lines if " -m sim_backend." in line]
    daemons = [line for line in lines if "/pneumad " in line]
    assert len(peers) == len(daemons) == 3
    return list(zip(peers, daemons))


def private(line: str, tmp_path) -> tuple[str, object, int]:
    """The line with the wire's address made the test's own, what tells the peer is up, and the
    CAN bus's UDP port (the README's lines use python-can's default: added by the test)."""
    link = str(tmp_path / "bridge")
    port = str(free_tcp_port())
    group, bus_port = private_bus()
    line = line.replace("/tmp/pneumad-bridge", link).replace("5020", port)
    line = re.sub(r"239\.74\.163\.2", group, line)
    return line, {"serial": lambda: os.path.exists(link), "modbus": lambda: listening(int(port))}, bus_port


@pytest.mark.parametrize("wire", ["serial", "modbus", "can"])
def test_the_readme_wire_lines_run_as_written(wire, tmp_path):
    peer_line, daemon_line = next(pair for pair in wire_pairs() if f"--transport {wire}" in pair[1])
    text = private(peer_line + "\n" + daemon_line, tmp_path)
    (peer_line, daemon_line), ready = text[0].splitlines(), text[1]
    bus_port = []  # a CAN bus's UDP port of its own too (tests/wirehelpers.private_bus says why)
    if wire == "can":
        peer_line, bus_port = f"{peer_line} --port {text[2]}", ["--transport-option", f"port={text[2]}"]
    peer = subprocess.Popen(["bash", "-c", "exec " + peer_line], cwd=tmp_path, stdout=subprocess.DEVNULL,
                            preexec_fn=as_device)
    daemon = None
    try:
        deadline = time.monotonic() + 60
        while wire in ready and not ready[wire]():
            assert peer.poll() is None and time.monotonic() < deadline, "the peer did not come up"
            time.sleep(0.1)
        eps = private_endpoints(tmp_path)
        endpoints = sum(([f"--{k}", v] for k, v in eps.items()), [])
        ours = [*LOADED, *WIRE_LOADED.get(wire, []), *bus_port, "--record-dir", str(tmp_path / "rec"),
                "--transport-option", "open_timeout_s=30", *endpoints]
        daemon = subprocess.Popen(["bash", "-c", "exec " + daemon_line + " " + " ".join(ours)], cwd=tmp_path)
        env = endpoint_env(eps)
        enabled_at = 0.0
        with Client(**eps, timeout=5.0) as client:
            wait_for_own_daemon(client, daemon)
            assert client.describe()["transport"]["backend"] == wire
            for line in ("enable", "set 130 -85 --duration 8 --wait"):
                done = subprocess.run(["bash", "-c", f"{BIN}pneumactl {line}"], env=env, capture_output=True,
                                      text=True, timeout=120)
                assert done.returncode == 0, (line, done.stderr, client.status()["cause"])
                enabled_at = enabled_at if line != "enable" else time.monotonic()
            time.sleep(max(0.0, enabled_at + 10.0 - time.monotonic()))  # 10 s enabled, the move among them
            status = client.status()
            # as one string: pytest shortens a tuple's dicts, and the counters are what tell a silent
            # wire (no replies) from one whose replies were refused (unexpected_seq, tx_dropped)
            assert status["state"] == "enabled" and status["trips"] == 0, f"{status['cause']}; {status['transport']}"
            assert abs(status["joints"]["bottom"]["angle_deg"] - 130.0) < 1.0
            assert status["transport"]["reads"] > 1000 and status["transport"]["errors"] == 0, status["transport"]
    finally:
        if daemon is not None:
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(timeout=20)
        peer.send_signal(signal.SIGTERM)
        peer.wait(timeout=20)
