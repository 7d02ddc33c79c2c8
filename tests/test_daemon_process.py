"""A real pneumad process: readiness and watchdog over sd_notify, SIGTERM leaves the safe
state, the dead-man command writes it from a fresh process, pneumactl drives it."""
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from daemon.recordings import reading as recording
from daemon.client.client import Client
from daemon.service.notify import Notifier
from daemon.testing.daemons import STOP_WAIT_S
from hal import config
from tests.daemons import running, tolerant_rig, tolerant_rig_text, wait_for_own_daemon
from tests.schemas import schema

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def rig_file(tmp_path: Path) -> Path:
    text = tolerant_rig_text().replace('backend = "sim"', 'backend = "tests.plugins:RecordingTransport"')
    text = text.replace("[transport.options]\n", f"[transport.options]\nrecord_to = \"{tmp_path / 'writes.json'}\"\n")
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def endpoints(tmp_path: Path) -> dict:
    return {name: f"ipc://{tmp_path}/{name}" for name in ("command", "control", "telemetry")}


def env_with(**extra) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT), **extra)
    env.pop("NOTIFY_SOCKET", None)
    env.update(extra)
    return env


class NotifyListener:
    """A notify socket read continuously, as systemd reads it (a datagram queue holds ~10)."""

    def __init__(self, path: str):
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(path)
        self.sock.settimeout(0.1)
        self.path = path
        self.received: list[tuple[float, str]] = []
        self._running = True
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self):
        while self._running:
            try:
                self.received.append((time.monotonic(), self.sock.recv(4096).decode()))
            except socket.timeout:
                pass

    def wait_for(self, text: str, limit: float = 120.0) -> bool:  # a busy machine starts slowly
        end = time.monotonic() + limit
        while time.monotonic() < end:
            if any(text in d for _, d in self.received):
                return True
            time.sleep(0.02)
        return False

    def count(self, text: str, since: float) -> int:
        return sum(text in d for t, d in self.received if t >= since)

    def wait_count(self, text: str, since: float, n: int, limit: float = 5.0) -> int:
        end = time.monotonic() + limit
        while self.count(text, since) < n and time.monotonic() < end:
            time.sleep(0.02)
        return self.count(text, since)

    def close(self):
        self._running = False
        self._thread.join()
        self.sock.close()


@pytest.fixture
def notify_socket(tmp_path):
    listener = NotifyListener(str(tmp_path / "notify"))
    yield listener
    listener.close()


@pytest.mark.slow(seconds=13)
def test_daemon_lifecycle_notify_sigterm_and_cli(tmp_path, notify_socket):
    eps = endpoints(tmp_path)
    rig = rig_file(tmp_path)
    # real-time scheduling as the service runs it (a loud fallback where it is not permitted)
    proc = subprocess.Popen([BIN / "pneumad", "--config", str(rig), *sum(([f"--{k}", v] for k, v in eps.items()), [])],
                            env=env_with(NOTIFY_SOCKET=notify_socket.path, WATCHDOG_USEC="200000"), stderr=subprocess.PIPE, text=True)
    try:
        assert notify_socket.wait_for("READY=1")
        since = time.monotonic()
        assert notify_socket.wait_count("WATCHDOG=1", since, 3) >= 3  # every 100 ms while healthy

        with Client(**eps, timeout=5.0) as c:
            c.acquire_lease(ttl_s=30.0)  # renewed each second below; the rig's 2 s ran out beside a busy machine
            c.enable()
            c.set(angles_deg=[130.0, -88.0], duration_s=3.0)
            for _ in range(4):
                time.sleep(1.0)
                c.renew_lease()
            status = c.status()
            assert status["state"] == "enabled"
            bottom = status["joints"]["bottom"]
            assert bottom["unit"] == "deg" and abs(bottom["position"] - 130.0) < 5.0
            c.release_lease()

        ctl = [BIN / "pneumactl", *sum(([f"--{k}", v] for k, v in eps.items()), [])]
        out = subprocess.run([*ctl, "status"], capture_output=True, text=True, env=env_with(), timeout=30)
        assert out.returncode == 0 and json.loads(out.stdout)["state"] == "enabled"
        rec = tmp_path / "run.mcap"
        out = subprocess.run([*ctl, "record", str(rec), "--seconds", "1"], capture_output=True, text=True,
                             env=env_with(), timeout=30)
        assert out.returncode == 0, out.stderr
        run = recording.open_run(rec)
        signals = [m["signals"] for m in run.messages["internals"]]  # the enabled PID's parts
        assert len(signals) > 50 and set(signals[-1]) == {"p", "i", "d"} and not run.truncated
        internals_schema = schema("telemetry", "internals")
        for message in run.messages["internals"]:  # as the daemon published them
            internals_schema.validate(message)
        assert [s["name"] for s in next(c for c in run.describe["controllers"] if c["name"] == "pid")["internals"]] \
            == ["p", "i", "d"]
        csv = tmp_path / "run.csv"
        out = subprocess.run([*ctl, "export", str(rec), str(csv)], capture_output=True, text=True, env=env_with(), timeout=30)
        assert out.returncode == 0, out.stderr
        lines = csv.read_text().splitlines()
        assert lines[0].startswith("cycle [-],t [s],bottom.position [rad],middle.position [rad]") and len(lines) > 500
        out = subprocess.run([*ctl, "controller", "set", "Kp=-3"], capture_output=True, text=True, env=env_with(), timeout=30)
        assert out.returncode == 1 and "outside" in out.stderr

        proc.send_signal(signal.SIGTERM)
        assert proc.wait(STOP_WAIT_S) == 0
        assert notify_socket.wait_for("STOPPING=1", limit=3)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    written = json.loads((tmp_path / "writes.json").read_text())
    safe = [0.0, 0.0, 0.0, 0.0]  # the built-in rig vents every chamber
    assert written["writes"][-1] == pytest.approx(safe, abs=1e-3)
    assert "SIGTERM" in proc.stderr.read()


SPAWNER = """import sys, time
from daemon.testing.daemons import spawn
daemon, eps = spawn(sys.argv[1], "--no-rt", "--spin-us", "0", "--config", sys.argv[2])
print(daemon.pid, flush=True)
time.sleep(600)
"""


def test_a_daemon_a_test_started_ends_with_the_tests_process_and_leaves_the_safe_state(tmp_path):
    """daemon.testing.daemons.spawn, as tests and benches start daemons: a test process killed
    without its teardown (an xdist worker gone, a bench killed) leaves no daemon cycling on. Its
    daemon gets SIGTERM and writes the safe state."""
    spawner = subprocess.Popen([sys.executable, "-c", SPAWNER, str(tmp_path), str(rig_file(tmp_path))],
                               stdout=subprocess.PIPE, text=True, env=env_with())
    pid = None
    try:
        pid = int(spawner.stdout.readline())
        with Client(**endpoints(tmp_path), timeout=5.0) as client:
            deadline = time.monotonic() + 60.0
            while True:
                try:
                    assert client.call("ping", timeout=1.0)["daemon"]["pid"] == pid
                    break
                except TimeoutError:
                    assert time.monotonic() < deadline, "the daemon never answered"
        spawner.kill()
        spawner.wait(STOP_WAIT_S)
        deadline = time.monotonic() + 30.0
        while running(pid):
            assert time.monotonic() < deadline, "the daemon outlived the process that started it"
            time.sleep(0.05)
    finally:
        if spawner.poll() is None:
            spawner.kill()
            spawner.wait()
        spawner.stdout.close()
        if pid is not None and running(pid):  # this test's failure: its daemon is still its to end
            os.kill(pid, signal.SIGTERM)
    written = json.loads((tmp_path / "writes.json").read_text())
    assert written["writes"][-1] == pytest.approx([0.0, 0.0, 0.0, 0.0], abs=1e-3)  # the built-in rig vents every chamber


def test_dead_man_command_writes_the_safe_state(tmp_path):
    rig = rig_file(tmp_path)
    out = subprocess.run([BIN / "pneumad", "safe-state", "--config", str(rig)], capture_output=True, text=True,
                         env=env_with(), timeout=60)
    assert out.returncode == 0, out.stderr
    assert "safe state written" in out.stdout
    written = json.loads((tmp_path / "writes.json").read_text())
    assert written["writes"] == [[0.0, 0.0, 0.0, 0.0]]


def test_bad_config_exits_with_a_clear_message(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(config.load().source.replace("direction = 1", "direction = 7", 1))
    # private endpoints: a config that did load would bind them, never a lab daemon's
    out = subprocess.run([BIN / "pneumad", "--config", str(bad), "--no-rt",
                          *sum(([f"--{k}", v] for k, v in endpoints(tmp_path).items()), [])],
                         capture_output=True, text=True, env=env_with(), timeout=60)
    assert out.returncode == 2
    assert "joints[0].sensor.direction: must be +1 or -1" in out.stderr


def test_notifier_speaks_to_an_abstract_socket():
    name = f"pneumad-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2)
    n = Notifier({"NOTIFY_SOCKET": "@" + name, "WATCHDOG_USEC": "3000000"})
    assert n.watchdog_interval == pytest.approx(1.5)
    assert n.ready("idle")
    assert sock.recv(4096).decode().splitlines()[:2] == ["READY=1", "STATUS=idle"]
    assert n.watchdog() and sock.recv(4096) == b"WATCHDOG=1"
    sock.close()
    assert not Notifier({}).ready("x")  # not under systemd: a no-op


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed here")
def test_unit_file_verifies(tmp_path):
    unit = tmp_path / "pneumad.service"
    text = (ROOT / "systemd" / "pneumad.service").read_text()
    unit.write_text(text.replace("/opt/pneumad/.venv/bin/", str(BIN) + "/"))
    out = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True)
    problems = [line for line in out.stderr.splitlines() if str(unit) in line]  # a clean unit says nothing
    assert not problems, out.stderr


def test_latency_qualification_reports_and_judges():
    out = subprocess.run([BIN / "pneumad", "latency", "--seconds", "0.5", "--no-rt"], capture_output=True,
                         text=True, env=env_with(), timeout=60)
    assert out.returncode == 0, out.stderr
    text = out.stdout
    assert "wake-up latency histogram" in text and "p99.9" in text
    assert any(text.split("verdict: ")[1].startswith(v) for v in ("GOOD", "USABLE", "NOT SUITABLE"))


@pytest.mark.parametrize("p999, worst, overruns, word", [
    (50.0, 200.0, 0, "GOOD"), (50.0, 200.0, 2, "USABLE"), (200.0, 900.0, 0, "USABLE"), (400.0, 900.0, 0, "NOT"),
    (50.0, 1500.0, 0, "NOT")])
def test_latency_verdict_bounds(p999, worst, overruns, word):
    from daemon.latency import verdict
    assert verdict({"p99.9": p999, "max": worst}, overruns, 0.001).startswith(word)


@pytest.mark.slow  # long: kept out of the fast subset
def test_a_recording_that_runs_out_of_disk_ends_with_a_clear_error(tmp_path):
    """/dev/full answers every write with ENOSPC, as a full disk does: pneumactl record says
    so and exits 1, and the daemon is not touched by it."""
    eps = endpoints(tmp_path)
    # the stall-tolerant rig (tests.daemons says why): a busy machine's stall is not this test's subject
    daemon = subprocess.Popen([BIN / "pneumad", "--no-rt", "--log-level", "WARNING", "--config", str(tolerant_rig(tmp_path)),
                               "--record-dir", str(tmp_path / "recordings"),
                               *sum(([f"--{k}", v] for k, v in eps.items()), [])], env=env_with(), cwd=tmp_path)
    try:
        with Client(**eps, timeout=5.0) as client:
            wait_for_own_daemon(client, daemon)  # its start waited for, however busy the machine
        ctl = [BIN / "pneumactl", *sum(([f"--{k}", v] for k, v in eps.items()), []), "--timeout", "30"]
        assert subprocess.run([*ctl, "status"], capture_output=True, env=env_with(), timeout=60).returncode == 0
        out = subprocess.run([*ctl, "record", "/dev/full", "--seconds", "1"], capture_output=True, text=True,
                             env=env_with(), timeout=60)
        assert out.returncode == 1 and "No space left on device" in out.stderr, out.stderr
        assert "Traceback" not in out.stderr
        status = subprocess.run([*ctl, "status"], capture_output=True, text=True, env=env_with(), timeout=60)
        assert json.loads(status.stdout)["trips"] == 0
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


def test_the_units_command_lines_are_ones_pneumad_accepts():
    """ExecStart, ExecStopPost: every option the unit gives exists (systemd-analyze cannot tell)."""
    import shlex

    from daemon.main import parser

    text = (ROOT / "systemd" / "pneumad.service").read_text().replace("\\\n", " ")
    lines = [line.split("=", 1)[1] for line in text.splitlines() if line.startswith(("ExecStart=", "ExecStopPost="))]
    assert len(lines) == 2
    for line in lines:
        args = parser().parse_args(shlex.split(line)[1:])
        assert args.config == "/etc/pneumad/rig.toml"
    assert parser().parse_args(shlex.split(lines[0])[1:]).keys == "/etc/pneumad/keys"
