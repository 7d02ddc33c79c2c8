"""pneumactl against a real daemon, as a user runs it: a waypoint file's columns go to the
joints they name, a linear axis takes its waypoints in mm; ``--wait`` that sees the arm leave
``enabled`` exits non-zero, so ``... --wait && next`` goes no further."""
from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import pytest

from daemon.client.client import Client
from daemon.testing.daemons import STOP_WAIT_S
from tests.daemons import answering_daemon, endpoint_env, real_daemon, wait_for_own_daemon

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    with answering_daemon(tmp_path_factory.mktemp("ctl")) as served:
        yield served


def pneumactl(eps, cwd, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daemon.client.ctl", *args], cwd=cwd, env=endpoint_env(eps),
                          capture_output=True, text=True, timeout=120)


def enabled(client: Client, eps, cwd) -> None:
    """The arm enabled with nothing running (a trip an earlier test caused reset)."""
    state = client.status()["state"]
    if state in ("fault", "estop"):
        assert pneumactl(eps, cwd, "reset").returncode == 0
    if client.status()["state"] != "enabled":
        assert pneumactl(eps, cwd, "enable").returncode == 0
    client.call("abort", control=True)


def test_waypoint_columns_go_to_the_joints_they_name(daemon):
    client, eps, tmp_path = daemon
    assert client.joint_units() == [("bottom", "deg"), ("middle", "deg")]
    enabled(client, eps, tmp_path)
    (tmp_path / "swapped.csv").write_text("duration_s,middle_deg,bottom_deg\n0,-80,120\n1,-78,125\n")
    done = pneumactl(eps, tmp_path, "waypoints", "swapped.csv", "--wait")
    assert done.returncode == 0, done.stderr
    joints = client.status()["joints"]
    assert joints["bottom"]["setpoint"] == pytest.approx(125.0) and joints["middle"]["setpoint"] == pytest.approx(-78.0)
    (tmp_path / "foo.csv").write_text("duration_s,foo_deg,bar_deg\n0,-80,120\n1,-78,125\n")
    done = pneumactl(eps, tmp_path, "waypoints", "foo.csv")
    assert done.returncode != 0 and "foo_deg,bar_deg not this rig's joints" in done.stderr, done.stderr
    assert "duration_s,bottom_deg,middle_deg (any order)" in done.stderr


def test_a_linear_axis_takes_its_waypoints_in_mm(tmp_path):
    from tests.test_axis_control import tolerant_axis
    proc, eps = real_daemon(tmp_path, "--config", str(tolerant_axis(tmp_path)), "--controller", "axis_pid")
    try:
        with Client(**eps, timeout=5.0) as client:
            wait_for_own_daemon(client, proc)
            assert client.joint_units() == [("axis", "mm")]
            enabled(client, eps, tmp_path)
            (tmp_path / "axis.csv").write_text("duration_s,axis_mm\n0,80\n1,120\n")
            done = pneumactl(eps, tmp_path, "waypoints", "axis.csv", "--wait")
            assert done.returncode == 0, done.stderr
            assert json.loads(done.stdout)["points"] == 2
            assert client.status()["joints"]["axis"]["setpoint"] == pytest.approx(120.0)
    finally:
        proc.terminate()
        proc.wait(STOP_WAIT_S)


def test_wait_exits_non_zero_when_the_arm_leaves_enabled_before_the_end(daemon):
    client, eps, tmp_path = daemon
    enabled(client, eps, tmp_path)
    proc = subprocess.Popen([sys.executable, "-m", "daemon.client.ctl", "set", "125", "-78", "--duration", "30",
                             "--wait"], cwd=tmp_path, env=endpoint_env(eps), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stderr.readline, "")), daemon=True)
    reader.start()
    deadline = time.monotonic() + 60.0
    while not any("of 30.0 s" in line for line in lines):  # following: its first progress line
        assert proc.poll() is None and time.monotonic() < deadline, lines
        time.sleep(0.1)
    client.estop("test")
    out = proc.stdout.read()  # to its end (the process has exited); its stderr is the reader's alone
    proc.wait(STOP_WAIT_S)
    reader.join(10)
    assert proc.returncode == 4, (out, lines)
    assert json.loads(out)["state"] == "estop"
    assert "the reference did not end: the arm is estop" in lines[-1]
    assert "4 --wait: the reference did not end" in pneumactl(eps, tmp_path, "--help").stdout


@pytest.mark.parametrize("setting, words", [
    ("Kp=nan", "Kp=nan: not a finite number"), ("Ti=inf", "Ti=inf: not a finite number"),
    ("Kp=[1,NaN]", "Kp=[1,NaN]: not a finite number"), ("Kp=abc", "Kp"),
])
def test_a_controller_setting_that_is_not_a_finite_number_is_refused_clearly(daemon, setting, words):
    client, eps, tmp_path = daemon
    before = client.controller()
    done = pneumactl(eps, tmp_path, "controller", "set", setting)
    assert done.returncode in (1, 2) and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.startswith("error: ") and words in done.stderr, done.stderr
    assert client.controller() == before


def test_a_request_over_the_message_limit_is_refused_before_it_is_sent(daemon):
    """4000 waypoints: refused at once with the limit and the catalog's 1000 points, not left
    to the transport (which answered nothing, and the client waited out its time)."""
    client, eps, tmp_path = daemon
    enabled(client, eps, tmp_path)
    rows = "".join(f"{0 if i == 0 else 0.5},{120 + (i % 10) * 0.1:.3f},-80\n" for i in range(4000))
    (tmp_path / "wp4000.csv").write_text("duration_s,bottom_deg,middle_deg\n" + rows)
    done = pneumactl(eps, tmp_path, "waypoints", "wp4000.csv")
    assert done.returncode == 1 and "no reply" not in done.stderr, done.stderr
    assert "over the daemon's limit of 65536 bytes a request: not sent" in done.stderr, done.stderr
    assert "'positions' holds 4000 items, at most 1000" in done.stderr
    assert client.status()["reference"] in (None, "hold")
