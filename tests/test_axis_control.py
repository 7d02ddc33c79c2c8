"""``pneumad --config sim-axis`` as a client drives it: axis_pid and the model-based axis_pva take
position steps and a smooth trajectory in mm (``steps``, ``waypoints``: bench.axis_control's
requests), while two CPU hogs run beside the daemon; their figures (rise and settling time,
overshoot, steady-state error; the trajectory's max and RMS error, all in mm) hold generous
bounds around docs/controllers.md's ("The linear axis"), settling judged into the friction hunt.
Also: the controllers refused on a rig they cannot drive, naming those that can, and a rig
file's [controllers.NAME] table."""
from __future__ import annotations

import math
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from bench import axis_control as bench
from controllers import registry
from controllers.base import ControllerContext, ParamError
from daemon import assembly
from daemon.client.client import Client
from daemon.loop.recovery import Recovery
from daemon.loop.settle import SettleGate
from daemon.planner.commands import PLANNERS
from daemon.planner.plans import PlanContext
from daemon.testing.daemons import STOP_WAIT_S
from daemon.wire.arguments import CommandFailed
from daemon.testing.simrig import DT, make_rig
from hal import config
from hal.errors import ConfigError
from tests.daemons import real_daemon, wait_for_own_daemon
from tests.schemas import schema


# A busy loop that ends with the test's process (an interrupted run leaves none spinning), at nice
# 19: other work on the lab PC. At nice 0 two hogs on this 2-core machine starve the --no-rt
# loop for tens of ms at a time, and the simulated plant catches such a gap up with the valve's
# command held (sim_backend/options.py, beside_loop): a step's saturated valve drove the piston
# into its end stop, a sensor fault, as it would on a real axis whose loop stalled
HOG = "import os, sys\nos.nice(19)\nparent = int(sys.argv[1])\nwhile os.getppid() == parent:\n    pass"


SETTLE_BAND_MM = 2.5  # the settling band here; the document's is 1 mm, inside which both hunt on the friction
SETTLE_HELD_S = 0.5  # settled: inside the band for this long [s]
HUNT_MM = 5.0  # the friction hunt's bound once settled [mm]: a slip's jump is ~1-3 mm, more if the loop was late in it


def settled_into_the_hunt(t, x_mm, t0: float, level_mm: float, end_t: float) -> tuple[float, float]:
    """When the step at ``t0`` [s] to ``level_mm`` first stayed ``SETTLE_HELD_S`` inside
    +-``SETTLE_BAND_MM`` before ``end_t`` (s from ``t0``; NaN: never), and the largest
    |x - level| [mm] from then to ``end_t``: the stick-slip hunt's reach.

    Not "settled for good" (bench.axis_control's figure): at rest both controllers hunt on the
    seals' friction, each slip a jump of 1-3 mm, and beside the hogs a slip the loop was late in
    runs on with the valve held (the simulated plant catches a gap up so), so the last exit from
    a 2.5 mm band can come at any time of the hold; the hunt is bounded instead."""
    t, x = np.asarray(t, float), np.asarray(x_mm, float)
    keep = (t >= t0) & (t < end_t)
    t, err = t[keep] - t0, np.abs(x[keep] - level_mm)
    inside = err <= SETTLE_BAND_MM
    start = None
    for k in range(t.size):
        if not inside[k]:
            start = None
        elif start is None:
            start = k
        if start is not None and t[k] - t[start] >= SETTLE_HELD_S:
            return float(t[start]), float(np.max(err[start:]))
    return math.nan, math.nan


def axis_samples(message: dict) -> list[tuple[int, float, float, float]]:
    """(cycle, t [s], position [m], set-point [m]) of the axis (the rig's one joint) per row of a
    ``state`` message: the one place that reads the message's shape."""
    return list(zip(message["cycle"], message["t"], message["axis.position"], message["axis.setpoint"]))


def tolerant_axis(tmp_path):
    """sim-axis with a stall limit of 5 s (tests/daemons.py, tolerant_rig_text: why)."""
    text = config.load("sim-axis").source.replace("stall_after_s = 0.05\n", "stall_after_s = 5.0\n")
    assert "stall_after_s = 5.0" in text
    path = tmp_path / "sim-axis.toml"
    path.write_text(text)
    return path


class Collector:
    """The daemon's state stream in a thread of its own, as axis samples."""

    def __init__(self, client: Client):
        self.sub = client.subscribe((b"state",))
        self.samples: list[tuple[int, float, float, float]] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while not self.stop.is_set():
            got = self.sub.receive(0.2)
            if got is not None:
                self.samples += axis_samples(got[1])

    def wait_for_cycle(self, cycle: int, limit_s: float = 60.0) -> float:
        """The t [s] of the first sample at ``cycle`` or later, once one has come."""
        end = time.monotonic() + limit_s
        while True:
            late = [s for s in self.samples[-2000:] if s[0] >= cycle]
            if late:
                return late[0][1]
            assert time.monotonic() < end, f"no state sample at cycle {cycle}"
            time.sleep(0.05)

    def wait_until(self, t: float, limit_s: float = 120.0) -> None:
        end = time.monotonic() + limit_s
        while not self.samples or self.samples[-1][1] < t:
            assert time.monotonic() < end, f"the daemon's clock did not reach {t} s"
            time.sleep(0.05)

    def close(self):
        self.stop.set()
        self.thread.join(5)
        self.sub.close()


def drive(client: Client, collector: Collector, controller: str) -> dict:
    """bench.axis_control's requests under ``controller``, through the daemon; the figures, each
    step's with its ``settled_s`` and ``hunt_mm`` (:func:`settled_into_the_hunt`)."""
    assert client.switch_controller(controller)["active"] == controller
    reply = client.call("set", {"positions": [bench.START_MM], "duration_s": 1.0})
    collector.wait_until(collector.wait_for_cycle(reply["cycle"]) + 2.5)
    marks = []
    for cmd, args in bench.REQUESTS:
        reply = client.call(cmd, args)
        marks.append(collector.wait_for_cycle(reply["cycle"]))
        end = time.monotonic() + 120.0  # a path waits for the axis to settle on its start first (up to 10 s)
        while client.status()["reference_remaining_s"] > 0.0:
            assert time.monotonic() < end, f"{cmd} did not end"
            time.sleep(0.1)
        collector.wait_until(collector.samples[-1][1] + 1.0)
        status = client.status()
        assert status["state"] == "enabled", (controller, cmd, status["cause"])
    t, x, r = zip(*[(s[1], s[2] * 1e3, s[3] * 1e3) for s in collector.samples if s[1] >= marks[0] - 0.5])
    path_t0 = bench.path_start(t, r, marks[1])
    found = bench.figures(t, x, r, marks[0], path_t0, path_t0 + (len(bench.PATH) - 1) * bench.LEG_S, SETTLE_BAND_MM)
    for k, (step, level) in enumerate(zip(found["steps"], bench.STEPS)):
        t0 = marks[0] + k * bench.HOLD_S
        step["settled_s"], step["hunt_mm"] = settled_into_the_hunt(t, x, t0, level[0], t0 + bench.HOLD_S)
    return found


@pytest.mark.slow(seconds=60)
def test_both_controllers_take_steps_and_a_trajectory_in_mm_beside_two_cpu_hogs(tmp_path):
    rig = tolerant_axis(tmp_path)
    hogs = [subprocess.Popen([sys.executable, "-c", HOG, str(os.getpid())]) for _ in range(2)]
    daemon = None
    try:
        daemon, eps = real_daemon(tmp_path, "--config", str(rig), "--controller", "axis_pid")
        with Client(**eps, timeout=120.0) as client:
            wait_for_own_daemon(client, daemon)
            client.acquire_lease(ttl_s=30.0)  # renewals beside the hogs can be late by seconds
            client.keep_lease()
            client.enable()
            collector = Collector(client)
            try:
                found = {name: drive(client, collector, name) for name in bench.CONTROLLERS}
            finally:
                collector.close()
    finally:
        if daemon is not None:
            daemon.terminate()
            daemon.wait(STOP_WAIT_S)
        for hog in hogs:
            hog.kill()
            hog.wait(STOP_WAIT_S)
    for name, figures in found.items():  # docs/controllers.md: rise 0.06-0.36 s, overshoot 2-6 %
        for step in figures["steps"]:
            assert not math.isnan(step["settled_s"]), (name, figures)  # within the hold
            assert step["hunt_mm"] < HUNT_MM, (name, figures)
            assert step["rise_s"] < 1.0, (name, figures)
            assert step["overshoot_pct"] < 30.0, (name, figures)
            assert abs(step["steady_state_error_mm"]) < 2.5, (name, figures)
        path = figures["path"]
        assert path["max_error_mm"] < 10.0 and path["rms_error_mm"] < 4.0, (name, figures)
    pva, pid = found["axis_pva"], found["axis_pid"]  # the model-based one rises faster and tracks closer
    assert all(a["rise_s"] < b["rise_s"] for a, b in zip(pva["steps"], pid["steps"])), found
    assert pva["path"]["rms_error_mm"] < pid["path"]["rms_error_mm"], found


def test_a_controller_is_refused_on_a_joint_it_cannot_drive_naming_those_that_can():
    axis = make_rig(name="sim-axis")
    with pytest.raises(ParamError, match=r"pid drives cylinder joints; joint 'axis' is a valve "
                                         r"\(controllers for it: hold, axis_pid, axis_pva\)"):
        registry.build("pid", axis.context())
    arm = make_rig()
    with pytest.raises(ParamError, match=r"axis_pva drives valve joints; joint 'bottom' is a cylinder "
                                         r"\(controllers for it: .*pid, hold\)"):
        registry.build("axis_pva", arm.context())


def test_the_rig_files_controllers_table_gives_the_defaults_and_refuses_unknown_names():
    sim = make_rig(name="sim-axis")
    pid = registry.build("axis_pid", sim.context())
    assert pid.get_params()["Kp"] == [150.0] and pid.get_params()["Kff"] == [6.8]  # hal/sim_axis.toml's
    assert registry.build("axis_pid", sim.context(), {"Kp": 90.0}).get_params()["Kp"] == [90.0]
    bare = ControllerContext.for_rig(sim.rig, sim.actuation, DT)
    bare = ControllerContext(bare.joint_names, DT, bare.u_min, bare.u_max, bare.models, bare.actuations,
                             bare.commands, bare.muscles, bare.axes)
    assert registry.build("axis_pid", bare).get_params()["Kp"] == [100.0]  # the class's own
    for old, new, match in (
            ("Kp = 150.0", "Kq = 1.0", r"controllers\.axis_pid\.Kq: unknown parameter of axis_pid \(known: Kp, Ti, "
                                       r"Kd, Kff, Tt, filter_hz\)"),
            ("[controllers.axis_pid]", "[controllers.axis_pod]", r"controllers\.axis_pod: .*'axis_pod'"),
            ("Kp = 150.0", "Kp = -1.0", r"the rig file's \[controllers\.axis_pid\]: axis_pid\.Kp\[axis\] = -1\.0 V/m "
                                        r"is outside 0\.0\.\.100000\.0 V/m")):
        with pytest.raises(ConfigError, match=match):
            assembly.loop_parts(config.parse(sim.rig.source.replace(old, new, 1)), controller="hold")


def test_a_step_beyond_the_stroke_limits_or_the_valves_flow_is_refused_in_mm():
    """The planner's checks in the axis's own units, as the planner worker makes them."""
    sim = make_rig(name="sim-axis")
    ctx = PlanContext.of(sim.rig, sim.context())
    with pytest.raises(CommandFailed, match=r"joint axis set-point 195\.00 mm is outside its limits "
                                            r"10\.0\.\.190\.0 mm"):
        PLANNERS["set"](ctx, {"positions": [195.0]}, [0.1])
    with pytest.raises(CommandFailed, match=r"beyond the axis's flow or force: joint axis .* but the valve's flow "
                                            r"gives 64\d mm/s that way .* the shortest feasible duration is 0\.\d s"):
        PLANNERS["set"](ctx, {"positions": [180.0], "duration_s": 0.1}, [0.02])
    with pytest.raises(CommandFailed, match=r"angles_deg: joint axis is linear: give its position in mm with "
                                            r"positions"):
        PLANNERS["set"](ctx, {"angles_deg": [10.0]}, [0.1])
    reply = PLANNERS["set"](ctx, {"positions": [150.0], "duration_s": 1.0}, [0.1]).reply
    assert reply["target"] == pytest.approx([150.0]) and "target_deg" not in reply
    plan = PLANNERS["excite"](ctx, {"signal": "chirp", "joint": "axis", "amplitude_mm": 5.0, "f0_hz": 0.5,
                                    "f1_hz": 3.0, "duration_s": 5.0}, [0.1])
    assert plan.trajectory.definition["amplitude_mm"] == 5.0
    assert math.isclose(plan.trajectory.peak, 0.005, rel_tol=0.05)
    with pytest.raises(CommandFailed, match=r"joint axis at 185\.0 mm \+- 10\.0 mm \(amplitude_mm\) leaves its limits"):
        PLANNERS["excite"](ctx, {"signal": "chirp", "joint": "axis", "amplitude_mm": 10.0}, [0.185])
    # inside the limits but within the set-point margin of one: refused as a set-point there is
    with pytest.raises(CommandFailed, match=r"joint axis at 170\.0 mm \+- 1[0-9]\.[0-9] mm \(amplitude_mm\) comes within 5 mm "
                                            r"of its limits 10\.0\.\.190\.0 mm: references keep 5 mm inside \(the rig "
                                            r"file's \[safety\] setpoint_margin_mm\), so 15\.0\.\.185\.0 mm") as refused:
        PLANNERS["excite"](ctx, {"signal": "chirp", "joint": "axis", "amplitude_mm": 18.0}, [0.170])
    assert refused.value.data["margin_mm"] == 5.0 and refused.value.data["argument"] == "amplitude_mm"
    schema("error-data").validate(refused.value.data)
    assert PLANNERS["excite"](ctx, {"signal": "chirp", "joint": "axis", "amplitude_mm": 10.0}, [0.170]).trajectory
    with pytest.raises(CommandFailed, match=r"joint axis is linear: give the reference side's amplitude as "
                                            r"amplitude_mm"):
        PLANNERS["excite"](ctx, {"signal": "chirp", "joint": "axis", "amplitude_deg": 1.0}, [0.1])



def test_recovery_and_the_settle_before_a_path_are_in_mm_on_a_linear_joint():
    """Enabled 5 mm below its 10 mm limit, the axis is moved 2 mm inside at 20 mm/s (at least
    1 s), said in mm; going out by more than 1 mm trips, in mm. A path starts once the axis has
    been within 1 mm of its start for 0.25 s."""
    recovery = Recovery(["axis"], [(0.010, 0.190)], [0.005], 0.001, ["m"])
    assert recovery.targets == pytest.approx([0.012]) and recovery.move_s == pytest.approx(1.0)
    joint = recovery.summary["joints"]["axis"]
    assert joint == {"position_mm": pytest.approx(5.0), "limits_mm": pytest.approx([10.0, 190.0]),
                     "target_mm": pytest.approx(12.0)}
    assert recovery.check([0.0045]) is None
    assert recovery.check([0.0035]) == ("joint axis enabled outside its limits went further out: 3.5 mm, enabled at "
                                        "5.0 mm (limits 10.0..190.0 mm)")
    near, off = SettleGate(0.0, [0.100], 0.001, ["m"]), SettleGate(0.0, [0.100], 0.001, ["m"])
    assert not any(not near.waiting([0.1009]) for _ in range(249)) and not near.waiting([0.1009])
    assert all(off.waiting([0.1012]) for _ in range(1000))
    assert near.summary([0.1009]) == {"waited_s": pytest.approx(0.25), "settled": True,
                                      "error": pytest.approx([-0.9])}


def test_the_input_side_excite_on_the_axis_takes_its_band_in_mm():
    """Open loop on the valve: amplitude_v about the held command, the band in mm, refused beyond
    the stroke limits in mm; no nominal model, so no predicted excursion and no centring."""
    ctx = PlanContext.of(make_rig(name="sim-axis").rig, make_rig(name="sim-axis").context())
    args = {"side": "input", "signal": "steps", "joint": "axis", "amplitude_v": 0.2, "levels": [0.5, -0.5],
            "band_mm": 30.0}
    plan = PLANNERS["excite"](ctx, dict(args), [0.1])
    assert plan.trajectory.definition["band_mm"] == 30.0 and plan.trajectory.definition["operating_point_mm"] == [100.0]
    assert plan.reply["predicted_excursion_deg"] is None
    with pytest.raises(CommandFailed, match=r"joint axis at 170\.0 mm \+- 30\.0 mm \(band_mm\) leaves its limits "
                                            r"10\.0\.\.190\.0 mm"):
        PLANNERS["excite"](ctx, dict(args), [0.170])
