"""README.md's tour, read from README.md (through tests/doc_blocks.py) and run line by line
against a real daemon, as a user would type it: so the README cannot drift from what the
daemon does. What each line is changed by to run here is declared in tests/doc_claims.toml.

Each ``pneumactl`` line runs through bash as written (``.venv/bin/`` is this interpreter's
bin directory) and must exit 0. It runs in a temporary directory holding copies of what the
README's relative paths name (``examples/``, ``controllers/designs/``), so the tour's files
(``run.mcap``, ``run.csv``, ``plots/``) are its own and a user's in the checkout are never
touched; its daemon is on private endpoints that the lines reach through ``PNEUMAD_COMMAND``,
``PNEUMAD_CONTROL`` and ``PNEUMAD_TELEMETRY``, so a daemon on the default endpoints (the lab's
own) is never spoken to. Before a motion line the test waits for
the reference in force to end, as a user would (a motion command while another runs is
refused by design); ``watch`` is left with Ctrl-C once it has shown a cycle. The lines that only read
the tour's own recording (``export``, ``plot``) run beside the lines after them, as a user
could in another terminal; each still has to exit 0.
"""
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from daemon.recordings import mcap_log
from daemon.client.client import Client
from daemon.testing.daemons import STOP_WAIT_S
from tests import doc_blocks, doc_runs
from tests.daemons import (endpoint_env, free_tcp_ports, private_endpoints, tolerant_rig_text,
                           wait_for_own_daemon)
from tests.doc_blocks import BIN, ROOT
MOTION = ("set", "path", "waypoints", "steps", "excite")
FILES_ONLY = ("export", "plot")  # lines that read a finished recording and never speak to the daemon
TOUR_GRACE_S = 600.0  # [s] an unleased, holding arm's grace in the tour's rig (start_daemon says why)

pytestmark = pytest.mark.slow


def tour_lines() -> list[doc_blocks.Command]:
    """The ``pneumactl`` lines of the README's tour."""
    return doc_blocks.commands("README.md", "A short tour", match=r"^\.venv/bin/pneumactl ")


def wait_for_reference_end(client: Client, limit_s: float = 60.0) -> None:
    deadline = time.monotonic() + limit_s
    while (remaining := client.status()["reference_remaining_s"]) > 0:
        assert time.monotonic() + remaining < deadline, f"the reference runs {remaining:.1f} s more"
        time.sleep(min(remaining, 1.0) + 0.05)


def last_events(subscription, count: int = 6) -> list[str]:
    """The kinds and causes of the last ``count`` events the subscription has received."""
    seen = []
    while (item := subscription.receive(0.2)) is not None:
        seen.append(f"{item[1].get('kind')}: {item[1].get('cause', item[1].get('action', ''))}")
    return seen[-count:]


def tour_directory(tmp_path: Path) -> Path:
    """A working directory with copies of what the README's relative paths name."""
    work = tmp_path / "work"
    shutil.copytree(ROOT / "examples", work / "examples")
    shutil.copytree(ROOT / "controllers" / "designs", work / "controllers" / "designs")
    return work


def start_daemon(tmp_path: Path, cwd: Path) -> tuple[subprocess.Popen, dict[str, str]]:
    """The tour's daemon line on private endpoints (the lines reach it through the environment)."""
    eps = private_endpoints(tmp_path)
    # The README's line, with what tests/doc_claims.toml declares. As the README advises it:
    # real-time scheduling where the test may have it (root, as in CI), --no-rt otherwise.
    # Two changes to the rig, both for a loaded machine: its stall limit
    # (tests.daemons says why), and its grace for an arm holding with no lease holder. `path
    # translation --record --wait` hands the lease back once the path is in force and then
    # follows it to its recording's file; beside two CPU hogs the recorder (nice 5) wrote that
    # file more than the 60 s grace after the path had ended, and the daemon disabled the arm
    # as its rig file tells it to, before the tour's next motion line.
    text = tolerant_rig_text().replace("unleased_grace_s = 60.0", f"unleased_grace_s = {TOUR_GRACE_S}")
    assert f"unleased_grace_s = {TOUR_GRACE_S}" in text
    rig = tmp_path / "tour-rig.toml"
    rig.write_text(text)
    line, = doc_blocks.commands("README.md", "A short tour", match=r"^\.venv/bin/pneumad ", no_rt=no_rt(),
                                rig=str(rig), recordings=str(tmp_path / "recordings"), endpoints=options(eps))
    daemon = subprocess.Popen(["bash", "-c", "exec " + line.text], cwd=cwd)
    return daemon, eps


def no_rt(match=None) -> str:
    """``--no-rt`` where the test may not have real-time scheduling (not root), else nothing."""
    return "" if os.geteuid() == 0 else " --no-rt"


def options(eps: dict[str, str]) -> str:
    """The daemon's options for the endpoints ``eps``."""
    return " ".join(f"--{name} {address}" for name, address in eps.items())


def test_the_readme_keys_example_runs_as_written(tmp_path):
    """The "From a laptop: keys" lines, in a fresh directory: keys made, a daemon on every
    interface with them, and Alice's key answered by name."""
    # The README's ports are the lab daemon's: the test's daemon takes free ones, and Alice's
    # line reaches it through the environment, as a laptop's shell would set it.
    ports = dict(zip(("5560", "5561", "5562"), map(str, free_tcp_ports(3))))
    lines = doc_blocks.commands("README.md", "From a laptop: keys", ports=lambda m: ports[m.group(1)], no_rt=no_rt)
    assert len(lines) == 4 and " --keys " in lines[2].text and "--key alice.key_secret" in lines[3].text
    daemon_line = lines[2].text
    assert daemon_line.count("tcp://0.0.0.0:") == 3 and not re.search(r":556[0-2]\b", daemon_line)
    env = endpoint_env({name: f"tcp://127.0.0.1:{ports[default]}" for name, default in
                        (("command", "5560"), ("control", "5561"), ("telemetry", "5562"))})
    for line in lines[:2]:
        done = doc_runs.run(line, tmp_path, timeout=60)
        assert done.returncode == 0, done.explain()
    daemon = subprocess.Popen(["bash", "-c", "exec " + daemon_line], cwd=tmp_path)
    try:
        deadline = time.monotonic() + 60
        while True:
            assert daemon.poll() is None, "pneumad exited (is another daemon on the default endpoints?)"
            done = doc_runs.run(lines[3], tmp_path, env=env, timeout=60)
            if done.returncode == 0:
                break
            assert time.monotonic() < deadline, done.explain()
        assert '"name": "alice"' in done.stdout and '"mode": "curve"' in done.stdout
        assert json.loads(done.stdout)["daemon"]["pid"] == daemon.pid  # bash exec'd pneumad: the same process
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


@pytest.fixture(scope="module")
def tour(tmp_path_factory):
    """The tour's daemon in its working directory, started once for the last two tests of this
    module: the check of who answers the tour's lines (which changes nothing), then the tour."""
    tmp_path = tmp_path_factory.mktemp("tour")
    work = tour_directory(tmp_path)
    daemon, eps = start_daemon(tmp_path, work)
    try:
        yield tmp_path, work, daemon, eps
    finally:
        daemon.send_signal(signal.SIGTERM)
        daemon.wait(STOP_WAIT_S)


def test_the_tours_pneumactl_reaches_the_tests_own_daemon(tour):
    """The environment the tour's lines run in takes ``pneumactl`` to the test's daemon: its
    ping names that daemon (pid and the instance drawn at its start), and so does status."""
    _, work, daemon, eps = tour
    with Client(**eps, timeout=5.0) as client:
        ours = wait_for_own_daemon(client, daemon)
    for what in ("ping", "status"):  # (the tour's own status line, and ping beside it)
        done = subprocess.run(["bash", "-c", f"{BIN}pneumactl {what}"], cwd=work, env=endpoint_env(eps),
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
        assert json.loads(done.stdout)["daemon"] == ours and ours["pid"] == daemon.pid


@pytest.mark.slow(seconds=65)
def test_the_readme_tour_runs_as_written(tour):
    lines = tour_lines()
    assert len(lines) >= 15 and any(" watch" in line.text for line in lines)
    tmp_path, work, daemon, eps = tour
    env = endpoint_env(eps, PYTHONUNBUFFERED="1")
    beside = []  # (line, process) of the FILES_ONLY lines
    notes = 0  # the unleased arm's note, which the one-shot lines after `enable` would each have printed
    try:
        with Client(**eps, timeout=5.0) as client:
            wait_for_own_daemon(client, daemon)
            events = client.subscribe((b"event",))  # what the daemon did, for a failure's message
            for line in lines:
                words = line.written.split()
                if words[1] in MOTION:
                    wait_for_reference_end(client)
                if words[1] in FILES_ONLY:
                    beside.append((line, subprocess.Popen(["bash", "-c", line.text], cwd=work, env=env, text=True,
                                                          stdout=subprocess.PIPE, stderr=subprocess.PIPE)))
                    continue
                done = doc_runs.run(line, work, env=env, timeout=120)  # `watch`: Ctrl-C once it shows a cycle
                assert done.returncode == 0, (f"{done.explain()}\n{client.status()['cause']}\n"
                                              f"the daemon's last events: {last_events(events)}")
                if words[1] == "watch":
                    assert "cycle" in done.stdout, done.explain()
                    continue
                notes += done.stderr.count("note: the arm stays enabled")
                if line.written.endswith("path translation --record --wait"):  # the thesis's 15 s runs as it is
                    assert "is beyond this rig" not in done.stderr, done.stderr
                state = client.status()["state"]
                expected = {"enable": "enabled", "estop": "estop", "reset": "idle", "disable": "idle"}.get(words[1])
                assert expected in (None, state), (line, state)
                assert state != "fault", (line, client.status()["cause"])
            assert client.status()["trips"] == 0
            assert notes == 1  # told once, by the line that enabled the arm
            for line, proc in beside:
                out, err = proc.communicate(timeout=120)
                assert proc.returncode == 0, f"README.md:{line.line}: {line.written}\n{out}\n{err}"
            # the daemon's own recording of the translation, whole
            recorded, = (tmp_path / "recordings").glob("*-path-translation.mcap")
            cycles = [m["cycle"] for m in mcap_log.read(recorded).messages["state"]]
            assert len(cycles) > 20_000 and cycles == list(range(cycles[0], cycles[0] + len(cycles)))
            # the notebook lines, on the recording the tour made
            snippet = doc_blocks.snippet("README.md", "A short tour", match=r"recordings\.load\(").text
            shown = re.findall(r'data\["([^"]+)"\]', snippet)  # every key its comment shows is in the recording
            assert "middle.position" in shown
            check = f"\nmissing = [k for k in {shown!r} if k not in data]\nassert not missing, missing" \
                    "\nassert len(data['middle.position']) > 1000"
            done = subprocess.run([sys.executable, "-c", snippet + check], cwd=work, capture_output=True, text=True,
                                  timeout=60)
            assert done.returncode == 0, (snippet, done.stderr)
            assert {"run.mcap", "run.csv", "plots"} <= {p.name for p in work.iterdir()}
    finally:
        for _, proc in beside:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
