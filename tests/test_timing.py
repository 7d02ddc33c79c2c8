"""A loop that says when its timing is degraded: the messenger judges the loop's rate, missed
deadlines and control-stage time over the rig file's ``[timing]`` window, and the loop raises
a ``timing`` event, keeps a ``status`` field and applies the policy (warn, hold, trip), naming a
controller whose step is over its budget (daemon/messenger/timing.py, daemon/loop/timing.py)."""
import contextlib
import os
import signal
import subprocess
import sys
import time

import pytest

from daemon.client import plot_marks, plots, progress, watch
from daemon.client.client import Client, RemoteError
from daemon.recordings import reading
from daemon.testing.daemons import STOP_WAIT_S
from daemon.wire.arguments import CommandFailed
from daemon.messenger.timing import judge
from hal.rig_sections import TimingConfig
from tests.daemons import real_daemon, tolerant_rig_text, wait_for_own_daemon
from tests.schemas import schema

SLOW_STEP = "slow_step=tests.plugins:SlowStep"


def timing_rig(tmp_path, **timing) -> str:
    """The tolerant built-in rig with a ``[timing]`` table of ``timing``."""
    path = tmp_path / "timing-rig.toml"
    table = "".join(f"{key} = {value!r}\n".replace("'", '"') for key, value in timing.items())
    path.write_text(tolerant_rig_text() + "\n[timing]\n" + table)
    return str(path)


def step_only(tmp_path, policy: str) -> str:
    """A rig whose timing is judged by the control stage's time alone (the rate and the missed
    deadlines not judged: a loaded test machine misses deadlines of its own), over 2 s."""
    return timing_rig(tmp_path, window_s=2.0, min_rate_fraction=0.0, max_overrun_fraction=1.0, policy=policy)


class Events:
    """A subscription's events in the order they came, each taken once: an event the policy
    causes (a trip, a reference's end) comes before the ``timing`` event that says why."""

    def __init__(self, client: Client):
        self.sub = client.subscribe((b"event",))
        self.seen: list[dict] = []
        self.taken: set[int] = set()
        self.sub.wait_until_heard()

    def next(self, kind: str, limit_s: float = 90.0, **fields) -> dict:
        deadline = time.monotonic() + limit_s
        while True:
            for i, event in enumerate(self.seen):
                if i not in self.taken and event["kind"] == kind and all(event.get(k) == v for k, v in fields.items()):
                    self.taken.add(i)
                    return event
            assert time.monotonic() < deadline, f"no {kind} event {fields} within {limit_s} s: {self.seen}"
            got = self.sub.receive(1.0)
            if got is not None:
                self.seen.append(got[1])

    def close(self) -> None:
        self.sub.close()


def logged(log, words: tuple[str, ...], limit_s: float = 30.0) -> str:
    deadline = time.monotonic() + limit_s
    while True:
        for line in log.read_text().splitlines():
            if all(w in line for w in words):
                return line
        assert time.monotonic() < deadline, f"no log line with {words} in:\n{log.read_text()}"
        time.sleep(0.1)


def check_degraded_by_the_slow_step(event: dict, policy: str, action: str) -> None:
    schema("telemetry", "event").validate(event)
    assert event["degraded"] and event["reasons"] == ["step"] and event["policy"] == policy
    assert event["action"] == action and event["controller"] == "slow_step" and event["who"] == "messenger"
    assert event["control_us"] > 4000.0 and event["step_budget_us"] == 500.0  # a 5 ms sleep; half a 1 ms period
    assert event["rate_hz"] < 400.0 and event["expected_hz"] == 1000.0  # a 5 ms step: 200 cycles a second at most
    assert event["since_t"] < event["t"] and "controller slow_step's step took" in event["cause"]


@pytest.mark.slow(seconds=60)
def test_under_warn_a_5_ms_controller_step_is_an_event_naming_it_a_status_field_and_a_log_line(tmp_path):
    """The arm runs on (warn); once the controller is switched back to PID the verdict comes
    back within the limits, an event again."""
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:
        daemon, eps = real_daemon(tmp_path, "--config", step_only(tmp_path, "warn"), "--controller-plugin", SLOW_STEP,
                                  "--controller", "slow_step", stderr=stderr)
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            events = Events(client)
            client.acquire_lease()
            client.keep_lease()
            started = client.record_start("meanwhile")  # the daemon's own recording, across the span
            client.enable()
            degraded = events.next("timing")
            check_degraded_by_the_slow_step(degraded, "warn", "warn")
            assert "DEGRADED (step)" in watch._timing(client.status()["timing"]).plain
            status = client.status()
            schema("results", "status").validate(status)
            timing = status["timing"]
            assert status["state"] == "enabled" and timing["degraded"] and timing["controller"] == "slow_step"
            assert timing["since"] == pytest.approx(degraded["since_t"] + degraded["window_s"])
            assert timing["cause"] == degraded["cause"] and timing["policy"] == "warn"
            client.switch_controller("pid")
            recovered = events.next("timing", degraded=False)
            schema("telemetry", "event").validate(recovered)
            assert recovered["action"] == "none" and recovered["controller"] is None
            assert "back within the rig file's [timing] limits" in recovered["cause"]
            assert client.status()["timing"]["degraded"] is False and client.status()["state"] == "enabled"
            assert "within the rig file's limits" in watch._timing(client.status()["timing"]).plain
            client.record_stop(started["name"])
            path = progress.recording_file(client, started["name"])
            events.close()
        # the recording holds the span: its figures hatch it, and the plot says so in words
        run = reading.open_run(path)
        t = run.column("t")
        (a, b, cause), = plot_marks.degraded_spans(run.messages["event"], float(t[0]), 0.0, float(t[-1] - t[0]))
        assert a == pytest.approx(degraded["since_t"] - t[0]) and b == pytest.approx(min(recovered["t"], t[-1]) - t[0])
        assert "controller slow_step's step took" in cause
        (note,) = plots.hole_notes("meanwhile.mcap", run)
        assert note.startswith(f"meanwhile.mcap: the loop's timing was degraded in {b - a:.1f} s")
        for figure in plots.plot_runs([path], str(tmp_path / "plots"), [run]):
            assert os.path.getsize(figure) > 10_000
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    line = logged(log, ("pneumad messenger WARNING: timing: degraded (", "controller slow_step's step took"))
    assert line.endswith(f"[cycle {degraded['cycle']}, messenger]")
    logged(log, ("pneumad messenger INFO: timing: recovered (",))


@pytest.mark.slow(seconds=60)
def test_under_hold_a_5_ms_controller_step_is_replaced_by_the_fallback_and_the_running_reference_stopped(tmp_path):
    """A move runs under PID; the slow controller is switched in beneath it: the verdict puts
    the rig file's fallback controller (pid) in its place, stops the move and holds the arm
    where it is, with the journal line saying who was replaced and why; once the loop is back
    within its limits, motion is taken again."""
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:
        daemon, eps = real_daemon(tmp_path, "--config", step_only(tmp_path, "hold"), "--controller-plugin", SLOW_STEP,
                                  stderr=stderr)
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            events = Events(client)
            client.acquire_lease()
            client.keep_lease()
            client.enable()
            client.set(angles_deg=[130.0, -75.0], duration_s=120.0)
            client.switch_controller("slow_step")
            degraded = events.next("timing")
            check_degraded_by_the_slow_step(degraded, "hold", "fallback")
            assert degraded["fallback"] == "pid"
            replaced = events.next("controller", to="pid")
            assert replaced["from"] == "slow_step" and replaced["cause"].startswith("fallback: slow_step: its step took ")
            assert replaced["cause"].endswith("(median), over its budget of 500 us")
            cut = events.next("reference", action="end")
            assert cut["cut"] == "replaced by hold"
            status = client.status()
            assert status["state"] == "enabled" and status["reference_remaining_s"] == 0.0
            assert status["controller"] == "pid" and status["timing"]["fallback"] in ("pid", None)
            back = events.next("timing", degraded=False)  # the fallback's step is within the budget
            assert back["action"] == "none" and back["fallback"] is None
            client.set(angles_deg=[131.0, -75.0], duration_s=2.0)  # motion is taken again
            events.close()
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    logged(log, ("pneumad messenger", "slow_step", "pid", "over its budget of 500 us"))


def test_under_hold_motion_is_refused_while_the_timing_is_degraded():
    """The policy hold refuses motion while a verdict says degraded (the rate, the missed
    deadlines or a step over budget), saying which rule holds it."""
    from daemon.loop.timing import TimingVerdicts
    from daemon.testing.loop import make_loop
    loop, _, _ = make_loop(rig_text=tolerant_rig_text() + '\n[timing]\npolicy = "hold"\n')
    verdicts = TimingVerdicts(loop, loop.view, loop.events)
    verdicts.check_motion()  # nothing judged yet: taken
    verdicts.take({"degraded": True, "reasons": ["rate"], "rate_hz": 500.0, "expected_hz": 1000.0, "overruns": 2500,
                   "deadlines": 5000, "control_us": 30.0, "step_budget_us": 500.0, "window_s": 5.0, "t": 10.0,
                   "since_t": 5.0})
    with pytest.raises(CommandFailed) as refused:
        verdicts.check_motion()
    assert refused.value.data == {"reason": "timing"} and 'policy = "hold"' in str(refused.value)
    assert loop.controller.name == "pid"  # a rate verdict replaces no controller
    verdicts.take({"degraded": False, "reasons": [], "rate_hz": 1000.0, "expected_hz": 1000.0, "overruns": 0,
                   "deadlines": 5000, "control_us": 30.0, "step_budget_us": 500.0, "window_s": 5.0, "t": 15.0,
                   "since_t": 10.0})
    verdicts.check_motion()


def verdict(t: float, reasons: list[str], rate_hz: float = 1000.0, control_us: float = 30.0) -> dict:
    """A ``timing.verdict`` over the 5 s window ending at ``t`` [s]."""
    return {"degraded": bool(reasons), "reasons": reasons, "rate_hz": rate_hz, "expected_hz": 1000.0,
            "overruns": 0, "deadlines": 5000, "control_us": control_us, "step_budget_us": 500.0, "window_s": 5.0,
            "t": t, "since_t": t - 5.0}


def timing_events(loop) -> list[dict]:
    events = [e for e in loop.events.pending if e["kind"] == "timing"]
    loop.events.pending.clear()
    return events


def test_a_change_of_reasons_while_degraded_is_a_new_event_with_the_current_figures():
    """Degraded for the rate, then also for a controller over its step budget: a new event (and
    so a log line) naming the controller with that window's figures; the same reasons again are
    no new event, but status says the latest figures."""
    from daemon.loop.timing import TimingVerdicts
    from daemon.messenger.journal import line
    from daemon.testing.loop import make_loop
    loop, _, _ = make_loop(rig_text=tolerant_rig_text())
    verdicts = TimingVerdicts(loop, loop.view, loop.events)
    timing_events(loop)
    verdicts.take(verdict(10.0, ["rate"], rate_hz=31.0))
    first, = timing_events(loop)
    assert first["reasons"] == ["rate"] and "31 Hz" in first["cause"] and first["controller"] is None
    verdicts.take(verdict(11.0, ["rate"], rate_hz=450.0))
    assert timing_events(loop) == []  # the same reasons: no new event ...
    assert "450 Hz" in verdicts.status["cause"] and verdicts.status["since"] == 10.0  # ... but the figures now
    verdicts.take(verdict(12.0, ["rate", "step"], rate_hz=180.0, control_us=5100.0))
    second, = timing_events(loop)
    schema("telemetry", "event").validate({"seq": 2, "cycle": 1, "t": 12.0, **second})
    assert second["degraded"] and second["reasons"] == ["rate", "step"] and second["controller"] == "pid"
    assert "180 Hz" in second["cause"] and "controller pid's step took 5100 us" in second["cause"]
    assert "controller pid's step took 5100 us" in line(second) and verdicts.status["cause"] == second["cause"]
    assert verdicts.status["since"] == 10.0  # still the same degraded span
    verdicts.take(verdict(13.0, ["rate"], rate_hz=300.0))
    dropped, = timing_events(loop)  # the step back within budget: a change too
    assert dropped["reasons"] == ["rate"] and dropped["controller"] is None and "300 Hz" in dropped["cause"]
    verdicts.take(verdict(14.0, []))
    back, = timing_events(loop)
    assert not back["degraded"] and "back within" in back["cause"]


def test_under_trip_enable_is_refused_while_degraded_and_the_trip_quotes_the_current_verdict():
    """Under trip, enable while degraded would be tripped at the next verdict: refused, saying
    why; an arm enabled all the same is tripped with the figures of the verdict that tripped it,
    naming the slow controller, not those of the first crossing."""
    from daemon.loop.timing import TimingVerdicts
    from daemon.testing.loop import make_loop
    loop, _, _ = make_loop(rig_text=tolerant_rig_text() + '\n[timing]\npolicy = "trip"\n')
    loop.run(50)
    verdicts = TimingVerdicts(loop, loop.view, loop.events)
    verdicts.take(verdict(10.0, ["rate"], rate_hz=31.0))
    with pytest.raises(CommandFailed) as refused:
        verdicts.check_enable()
    assert refused.value.data == {"reason": "timing"} and 'policy = "trip"' in str(refused.value)
    assert "31 Hz" in str(refused.value) and "back within" in str(refused.value)
    loop.enable()  # the loop's own control, past the command's check: as if enabled just before the verdict came
    loop.run(10)
    verdicts.take(verdict(11.0, ["rate", "step"], rate_hz=180.0, control_us=5100.0))
    cause = loop.supervisor.cause
    assert loop.view.state.value == "fault" and "180 Hz" in cause and "controller pid's step took 5100 us" in cause
    verdicts.take(verdict(12.0, []))
    loop.reset()
    verdicts.check_enable()  # back within the limits: taken


def test_under_trip_the_enable_command_is_refused_while_degraded_saying_why():
    from daemon.testing.loop import call, dealer, make_loop, ok
    loop, _, srv = make_loop(rig_text=tolerant_rig_text() + '\n[timing]\npolicy = "trip"\n', server=True)
    try:
        sock = dealer(srv)
        lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
        srv.commands.timing.take(verdict(10.0, ["rate"], rate_hz=31.0))  # as the messenger's verdict would
        refused = call(loop, sock, "enable", lease=lease)["error"]
        assert refused["code"] == "bad_state" and refused["data"] == {"reason": "timing"}
        assert "31 Hz" in refused["message"] and 'policy = "trip"' in refused["message"]
        assert loop.state.value == "idle"
        srv.commands.timing.take(verdict(15.0, []))
        assert ok(loop, sock, "enable", lease=lease)["state"] == "enabled"
    finally:
        srv.close()


@pytest.mark.slow(seconds=60)
def test_under_trip_a_5_ms_controller_step_trips_the_enabled_arm_saying_why(tmp_path):
    with open(tmp_path / "daemon.log", "w") as stderr:
        daemon, eps = real_daemon(tmp_path, "--config", step_only(tmp_path, "trip"), "--controller-plugin", SLOW_STEP,
                                  "--controller", "slow_step", stderr=stderr)
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            events = Events(client)
            client.acquire_lease()
            client.keep_lease()
            client.enable()
            degraded = events.next("timing")
            check_degraded_by_the_slow_step(degraded, "trip", "trip")
            trip = events.next("trip")
            assert trip["cause"] == f"timing degraded: {degraded['cause']}" and trip["who"] == "messenger"
            status = client.status()
            assert status["state"] == "fault" and status["cause"] == trip["cause"] and status["timing"]["degraded"]
            events.close()
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


@pytest.mark.slow(seconds=90)
@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs a CPU for the loop and one for the rest")
def test_a_no_rt_loop_starved_of_its_cpu_says_its_timing_is_degraded_with_the_rate_it_achieved(tmp_path):
    """A --no-rt daemon on a loaded PC, made so on purpose: its loop pinned to one CPU and put
    at the lowest priority there (nice 19: it still cycles now and then beside other load, where
    SCHED_IDLE beside CPU hogs stopped it for good), and a busy process on that CPU. The loop
    cannot keep its 1 kHz; the verdict says degraded, with the rate it achieved, and the start
    line says it runs without real-time scheduling."""
    cpu = max(os.sched_getaffinity(0))
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:
        daemon, eps = real_daemon(tmp_path, "--config", timing_rig(tmp_path, window_s=2.0), "--cpus", str(cpu),
                                  stderr=stderr)
    hog = None
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            events = Events(client)
            os.setpriority(os.PRIO_PROCESS, daemon.pid, 19)  # the loop's thread (the main one)
            hog = subprocess.Popen([sys.executable, "-c", f"import os\nos.sched_setaffinity(0, {{{cpu}}})\n"
                                                          "while True: pass"])
            deadline = time.monotonic() + 90.0
            while not ((timing := client.status()["timing"])["degraded"] and "rate" in timing["reasons"]):
                assert time.monotonic() < deadline, f"the starved loop was never judged slow: {timing}"
                time.sleep(0.5)
            assert timing["rate_hz"] < 900.0 and timing["overruns"] > 0.02 * timing["deadlines"]
            degraded = events.next("timing", degraded=True)  # when it crossed (on this machine, maybe before)
            schema("telemetry", "event").validate(degraded)
            assert f"the loop ran at {degraded['rate_hz']:.0f} Hz of 1000 Hz" in degraded["cause"]
            events.close()
    finally:
        if hog is not None:
            hog.send_signal(signal.SIGKILL)
            hog.wait()
        with contextlib.suppress(PermissionError):  # its stop at nice 19 beside other load would take long
            os.setpriority(os.PRIO_PROCESS, daemon.pid, 0)
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    logged(log, ("pneumad WARNING: this PC: no real-time scheduling (--no-rt) on CPUs", "the loop's timing is at risk"))
    logged(log, ("pneumad messenger WARNING: timing: degraded (the loop ran at",))


def test_the_verdict_judges_the_rate_the_missed_deadlines_and_the_control_stage_against_each_limit():
    """judge() on figures: each limit crossed alone, and none."""
    limits = TimingConfig(window_s=5.0, min_rate_fraction=0.9, max_overrun_fraction=0.02, step_budget_fraction=0.5)
    calm = judge(limits, 0.001, 10.0, 15.0, 5000, 0, 40.0)
    assert not calm["degraded"] and calm["rate_hz"] == 1000.0 and calm["window_s"] == 5.0
    assert judge(limits, 0.001, 10.0, 15.0, 4400, 0, 40.0)["reasons"] == ["rate"]  # 880 Hz, though nothing overran
    assert judge(limits, 0.001, 10.0, 15.0, 4600, 150, 40.0)["reasons"] == ["overruns"]  # 920 Hz; 3.2 % missed
    assert judge(limits, 0.001, 10.0, 15.0, 5000, 0, 600.0)["reasons"] == ["step"]
    assert judge(limits, 0.002, 10.0, 15.0, 2500, 0, 600.0)["reasons"] == []  # a 2 ms period: a 1 ms budget
    assert judge(limits, 0.001, 10.0, 15.0, 5000, 0, float("nan"))["control_us"] is None  # no control stage timed
