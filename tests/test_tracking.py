"""The supervisor's rule for a controller that has lost a joint (issue: controllers at the
rig's edges): it trips, or hands the arm to the fallback controller, long before the joint
reaches its limit; a joint that is catching up on a large move is left alone."""
import math

import pytest

from bench import scenarios as S
from controllers import registry
from controllers.trajectory import JointMove, JointWaypoints
from daemon.loop.tracking import TrackingGuard
from hal import config
from hal.errors import ConfigError
from daemon.testing.loop import dealer, make_loop, ok, run_seconds

LOST_RIG = {'tracking_action = "trip"': 'tracking_action = "fallback"'}


def test_a_joint_outside_the_band_is_lost_only_when_it_does_not_close_in():
    guard = TrackingGuard(("a",), bound_deg=10.0, window_s=2.0)
    out = math.radians(15.0)
    assert guard.check(0.0, [0.0], [out]) is None  # the window starts
    assert guard.check(1.9, [0.0], [out]) is None
    cause = guard.check(2.0, [0.0], [out])
    assert cause is not None and "joint a lost" in cause and "15.0 deg" in cause
    closing = TrackingGuard(("a",), 10.0, 2.0)  # 15 deg, then 14, 13 ...: catching up
    assert all(closing.check(t, [0.0], [math.radians(15.0 - t / 2)]) is None for t in range(10))
    back = TrackingGuard(("a",), 10.0, 2.0)  # leaves the band, comes back, leaves again
    assert back.check(0.0, [0.0], [out]) is None and back.check(1.5, [0.0], [0.0]) is None
    assert back.check(1.6, [0.0], [out]) is None and back.check(3.5, [0.0], [out]) is None
    assert back.check(3.6, [0.0], [out]) is not None
    assert TrackingGuard(("a",), 0.0, 2.0).check(100.0, [0.0], [math.pi]) is None  # 0: off


def pushed_away(loop, seconds: float) -> float:
    """Push the middle joint with a torque worth 6 V (2 V beyond its -4 V) for up to ``seconds``;
    the middle angle [deg] when the loop left enabled (or at the end)."""
    loop.hold()
    loop.run(2000)
    loop.io.transport.arm.disturbance_nm[1] = loop.context.models[1].kt * 6.0
    for _ in range(int(seconds / loop.period)):
        loop.run(1)
        if loop.state.value != "enabled":
            break
    return math.degrees(loop.angles[1])


def test_a_joint_pushed_off_trips_with_who_and_why_well_inside_its_limit():
    loop = S.make_loop("pid")
    angle = pushed_away(loop, 20.0)
    assert loop.state.value == "fault"
    assert "controller pid: joint middle lost: tracking error" in loop.supervisor.cause
    high = loop.rig.joints[1].max_angle_deg
    assert high - angle > 15.0, f"tripped at {angle:.1f} deg, {high - angle:.1f} deg from the limit"
    assert loop.p_head == list(loop.io.safe_pressures[0]) and loop.p_rod == list(loop.io.safe_pressures[1])


def test_a_large_move_the_joint_is_catching_up_on_is_not_a_loss():
    loop = S.make_loop("pid")
    loop.hold()
    loop.run(2000)
    target = [loop.angles[0], loop.angles[1] + math.radians(35.0)]  # middle: over 10 s at its few deg/s
    loop.set_trajectory(JointMove(list(loop.angles), target, 0.0), "step")
    loop.run(25000)
    assert loop.state.value == "enabled", loop.supervisor.cause
    assert abs(math.degrees(target[1] - loop.angles[1])) < 2.0


def test_the_fallback_controller_takes_the_arm_and_holds_it_where_it_is():
    rig = config.load().source
    for old, new in LOST_RIG.items():
        assert old in rig
        rig = rig.replace(old, new)
    loop, captured, _ = make_loop(rig, plugins={"pushes_away": "tests.plugins:PushesAway"})
    loop.enable()
    loop.switch(registry.build("pushes_away", loop.context, plugins=loop.controller_plugins))
    loop.run(15000)
    assert loop.state.value == "enabled", loop.supervisor.cause
    assert loop.controller.name == "pid" and loop.trajectory_name == "hold"
    events = [m for m in captured.of("event") if m["kind"] == "tracking"]
    assert len(events) == 1 and events[0]["controller"] == "pushes_away" and events[0]["action"] == "fallback"
    assert events[0]["to"] == "pid" and "joint middle lost" in events[0]["cause"]
    held = loop.reference[0][1]
    loop.run(5000)
    assert abs(math.degrees(held - loop.angles[1])) < 1.0  # the fallback holds where it took over


def test_a_fallback_that_loses_the_joint_too_trips():
    rig = config.load().source
    for old, new in LOST_RIG.items():
        rig = rig.replace(old, new)
    rig = rig.replace('fallback_controller = "pid"', 'fallback_controller = "pushes_away"')
    loop, captured, _ = make_loop(rig, plugins={"pushes_away": "tests.plugins:PushesAway"})
    loop.enable()
    loop.switch(registry.build("pushes_away", loop.context, plugins=loop.controller_plugins))
    for _ in range(150):  # up to 15 s, until the trip (it latches; the fallback's loss comes at about 7.5 s)
        loop.run(100)
        if loop.state.value != "enabled":
            break
    assert loop.state.value == "fault" and "controller pushes_away: joint middle lost" in loop.supervisor.cause
    assert [m["action"] for m in captured.of("event") if m["kind"] == "tracking"] == ["trip"]


def test_a_sensor_stuck_during_a_move_is_caught_by_the_tracking_rule():
    loop = S.make_loop("pid")
    loop.hold()
    loop.run(2000)
    loop.io.transport.inject("stuck", "ai0")  # the bottom joint's wiper freezes
    target = [loop.angles[0] + math.radians(25.0), loop.angles[1]]
    loop.set_trajectory(JointMove(list(loop.angles), target, 3.0), "move")
    for _ in range(15000):
        loop.run(1)
        if loop.state.value != "enabled":
            break
    # caught once the reference has travelled 20 deg with no motion seen (the stuck rule), or by the
    # error band; the joint it cannot see runs at up to 27 deg/s meanwhile (docs/faults.md)
    assert loop.state.value == "fault" and "joint bottom stuck" in loop.supervisor.cause
    assert loop.p_head == list(loop.io.safe_pressures[0])


def sweep(theta: float, amplitude: float, cycles: int, per_half: float) -> list[float]:
    """Joint angles [rad] for a back-and-forth sweep of +-``amplitude`` [rad] about ``theta``."""
    return [theta] + [theta + (amplitude if k % 2 == 0 else -amplitude) for k in range(2 * cycles)] + [theta]


def test_a_joint_that_does_not_follow_a_sweeping_reference_is_stuck_though_never_outside_the_band():
    band, amplitude = 10.0, math.radians(8.0)  # the sweep never takes the error outside the band
    path = JointWaypoints([[a] for a in sweep(0.0, amplitude, 3, 4.0)], [4.0] * 7)
    stuck, follows, lags = (TrackingGuard(("a",), band, 2.0) for _ in range(3))
    found = {}
    for k in range(28000):
        t = k * 1e-3
        r = path.sample(t)[0]
        for name, guard, q in (("stuck", stuck, [0.0]), ("follows", follows, r),
                               ("lags", lags, [0.8 * path.sample(max(t - 0.5, 0.0))[0][0]])):  # 0.5 s late, 80 %
            cause = guard.check(t, r, q)
            if cause is not None:
                found.setdefault(name, (t, cause))
    assert set(found) == {"stuck"}, found
    t, cause = found["stuck"]
    assert "joint a stuck: moved 0.0 deg" in cause and t < 12.0  # 20 deg of reference travel: in the second sweep
    # a step (a jump in one cycle) is the error rule's, not travel; catching up on it is progress
    step = TrackingGuard(("a",), band, 2.0)
    assert step.check(0.0, [0.0], [0.0]) is None and step.check(0.001, [math.radians(35.0)], [0.0]) is None
    assert all(step.check(1.0 + k, [math.radians(35.0)], [math.radians(3.0 * k)]) is None for k in range(12))
    assert TrackingGuard(("a",), 0.0, 2.0).check(0.0, [1.0], [0.0]) is None  # 0: off


@pytest.mark.slow(seconds=7)
def test_a_seized_joint_under_a_sweep_the_error_band_never_sees_trips_as_stuck():
    """The middle joint held by a breakaway torque no cylinder reaches; its reference sweeps
    +-8 deg, inside the 10 deg band: only the progress rule can see it."""
    seized = {"joints": {"middle": {"overrides": {"Fs": 1000.0, "Fc": 1000.0}}}}
    for plant, joint in ((seized, 1), (None, 0)):  # seized middle joint; a healthy bottom joint on the same sweep
        loop = S.make_loop("pid", plant=plant)
        loop.hold()
        loop.run(2000)
        start = list(loop.angles)
        points = []
        for a in sweep(start[joint], math.radians(8.0), 2, 4.0):
            p = list(start)
            p[joint] = a
            points.append(p)
        loop.set_trajectory(JointWaypoints(points, [4.0] * 5), "sweep")
        for _ in range(200):  # up to 20 s
            loop.run(100)
            if loop.state.value != "enabled":
                break
        if plant is seized:
            assert abs(math.degrees(loop.angles[1] - start[1])) < 0.5  # it never moved
            assert loop.state.value == "fault" and "controller pid: joint middle stuck" in loop.supervisor.cause
        else:
            assert loop.state.value == "enabled", loop.supervisor.cause


SEIZED_BOTTOM = "\n[transport.options.joints.bottom]\noverrides = { Fs = 1000.0, Fc = 1000.0 }\n"  # none moves it


def chirp_under_pid(joint: str, amplitude_deg: float, rig_text: str | None = None, seconds: float = 31.0):
    """The thesis's closed-loop chirp (0.1-1 Hz log sweep over 30 s, on the reference) on
    ``joint`` under PID, asked of a served in-process loop as a client would; the loop run
    ``seconds`` past the request or until it leaves enabled. (loop, captured, cycle of the
    chirp's start)."""
    loop, captured, srv = make_loop(rig_text, server=True)
    try:
        sock = dealer(srv)
        lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
        ok(loop, sock, "enable", lease=lease)
        run_seconds(loop, 2.0)
        started = ok(loop, sock, "excite", {"signal": "chirp", "joint": joint, "amplitude_deg": amplitude_deg,
                                            "f0_hz": 0.1, "f1_hz": 1.0, "duration_s": 30.0}, lease)
        assert started["side"] == "reference" and started["duration_s"] == 30.0
        for _ in range(int(seconds * 10)):
            loop.run(100)
            if loop.state.value != "enabled":
                break
        return loop, captured, started["cycle"]
    finally:
        srv.close()


@pytest.mark.slow(seconds=60)
@pytest.mark.parametrize("joint", ["bottom", "middle"])
def test_a_loop_that_follows_the_thesis_chirp_with_lag_and_attenuation_is_not_stuck(joint):
    """Up to 1 Hz the PID loop lags its reference by a large phase and follows it at about
    half its amplitude (the middle joint): that is tracking, not a joint that does not move."""
    loop, captured, _ = chirp_under_pid(joint, 1.0)
    assert loop.state.value == "enabled", loop.supervisor.cause
    assert not [e for e in captured.of("event") if e["kind"] == "tracking"]
    ends = [e for e in captured.of("event") if e["kind"] == "reference" and e["action"] == "end"]
    assert [(e["name"], e["cut"]) for e in ends] == [("chirp", "")]  # ran to its end


@pytest.mark.slow(seconds=40)
def test_a_seized_joint_under_the_thesis_chirp_trips_once_its_reference_has_travelled_20_deg():
    """The same chirp at 2 deg (the most the rig's authority allows at 1 Hz; inside the 10 deg
    error band: only the travel rule can see it) on a bottom joint that cannot move: the
    reference travels 4 x (2 - 0.25) deg a cycle through the play, 20 deg after 2.9 cycles of
    the sweep (N(t) = f0 T / ln(f1 / f0) ((f1 / f0)^(t / T) - 1)), at 15.1 s."""
    loop, captured, start = chirp_under_pid("bottom", 2.0, config.load().source + SEIZED_BOTTOM, seconds=18.0)
    assert abs(math.degrees(loop.angles[0] - loop.reference[0][0])) < 2.5  # never near the band
    assert loop.state.value == "fault" and "controller pid: joint bottom stuck: moved 0.0 deg" in loop.supervisor.cause
    trip = [e for e in captured.of("event") if e["kind"] == "trip"][-1]
    assert 14.0 < (trip["cycle"] - start) * loop.period < 16.5


def test_a_fallback_controller_that_cannot_be_built_is_a_configuration_error():
    rig = config.load().source.replace('tracking_action = "trip"', 'tracking_action = "fallback"')
    with pytest.raises(ConfigError, match="safety.fallback_controller: unknown controller 'nope'"):
        make_loop(rig.replace('fallback_controller = "pid"', 'fallback_controller = "nope"'))


def test_an_unknown_start_controller_is_a_configuration_error():
    with pytest.raises(ConfigError, match="--controller: unknown controller 'nope'"):
        make_loop(controller="nope")
