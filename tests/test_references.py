"""More references: waypoint paths (joint and Cartesian), step sequences, and the chirp and
PRBS identification signals, as trajectories and through the command protocol."""
import math
import time

import msgpack
import numpy as np
import pytest
from scipy.signal import chirp, max_len_seq

from controllers import signals, trajectory
from daemon.wire import protocol as P
from hal import config, kinematics
from daemon.loop.settle import SETTLE_MAX_S, SettleGate
from daemon.testing.loop import call, dealer, make_loop, ok, run_seconds
from tests.schemas import schema


@pytest.fixture
def armed():
    """Enabled at rest with the lease held."""
    loop, captured, srv = make_loop(server=True)
    sock = dealer(srv)
    lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
    ok(loop, sock, "enable", lease=lease)
    run_seconds(loop, 2.0)
    yield loop, captured, sock, lease
    srv.close()


def test_the_log_chirp_has_scipys_phase_and_its_own_rates():
    sig = signals.LogChirp([0.3, -1.7], 0, 0.02, 0.1, 1.0, 20.0)
    t = np.linspace(0.0, 19.9, 400)
    expected = 0.02 * chirp(t, 0.1, 20.0, 1.0, method="logarithmic", phi=-90)
    np.testing.assert_allclose([sig.sample(x)[0][0] - 0.3 for x in t], expected, atol=1e-9)
    h = 1e-5
    for x in (0.5, 7.3, 19.0):
        r0, r1 = sig.offset(x - h), sig.offset(x + h)
        assert sig.offset(x)[1] == pytest.approx((r1[0] - r0[0]) / (2 * h), rel=1e-5)
        assert sig.offset(x)[2] == pytest.approx((r1[1] - r0[1]) / (2 * h), rel=1e-4)
    assert sig.sample(5.0)[0][1] == -1.7 and sig.sample(25.0)[0] == [0.3, -1.7]


def test_the_prbs_is_the_maximum_length_sequence_held_bit_by_bit():
    sig = signals.PRBS([0.0, 0.0], 1, 0.01, 5, 0.1, periods=2)
    bits = max_len_seq(5)[0]
    assert sig.duration == pytest.approx(31 * 0.1 * 2)
    seen = [sig.sample(0.05 + 0.1 * i)[0][1] for i in range(62)]
    assert seen == [0.01 if b else -0.01 for b in bits] * 2
    assert sum(seen) == pytest.approx(0.02)  # one more +1 than -1 per period: nearly zero mean


def test_joint_waypoints_pass_each_point_at_rest_at_its_time():
    points = [[0.0, -1.7], [0.2, -1.6], [0.1, -1.75]]
    path = trajectory.joint_waypoints(points, [2.0, 3.0])
    assert path.duration == 5.0
    for t, p in ((0.0, points[0]), (2.0, points[1]), (5.0, points[2])):
        q, w, _ = path.sample(t)
        assert q == pytest.approx(p) and w == pytest.approx([0.0, 0.0], abs=1e-12)


def test_cartesian_waypoints_run_straight_lines_between_the_points():
    lengths = (0.1, 0.1)
    pts = [(70.0, 135.0), (20.0, 150.0), (-20.0, 135.0)]
    path = trajectory.cartesian_waypoints(lengths, 1, 2, pts, [4.0, 6.0])
    for t, (a, b), frac in ((2.0, (pts[0], pts[1]), 0.5), (7.0, (pts[1], pts[2]), 0.5), (4.0, (pts[0], pts[1]), 1.0)):
        x, y = kinematics.forward(path.sample(t)[0][:2], lengths)
        assert (x * 1e3, y * 1e3) == pytest.approx((a[0] + frac * (b[0] - a[0]), a[1] + frac * (b[1] - a[1])), abs=1e-6)


@pytest.mark.slow(seconds=4)  # a few seconds: kept out of the fast subset
def test_a_joint_waypoint_path_is_followed_to_its_last_point(armed):
    loop, captured, sock, lease = armed
    here = [math.degrees(q) for q in loop.reference[0]]
    points = [here, [here[0] + 5, here[1] + 2], [here[0] - 3, here[1]]]
    result = ok(loop, sock, "waypoints", {"angles_deg": points, "durations_s": [10.0, 10.0], "approach_s": 0.5},
                lease)
    assert result["points"] == 3 and result["duration_s"] == 20.0
    # to the first waypoint on the path's own clock, which starts once the arm has settled on
    # the path's start (the loop runs on while the reply comes back)
    while "settled" not in reference_events(captured, "waypoints"):
        loop.run(10)
    run_seconds(loop, 10.5 - (loop.clock.now() - loop.trajectory_t0))
    assert [math.degrees(q) for q in loop.reference[0]] == pytest.approx(points[1], abs=1e-6)
    run_seconds(loop, 20.0)
    assert [math.degrees(q) for q in loop.angles] == pytest.approx(points[2], abs=0.5)
    assert loop.state.value == "enabled"


def test_a_waypoint_path_too_fast_for_the_rig_is_refused_with_the_duration_that_would_do(armed):
    loop, _, sock, lease = armed
    args = {"xy_mm": [[70, 135], [20, 150], [-20, 135]], "durations_s": [1.0, 1.0], "approach_s": 20.0}
    reply = call(loop, sock, "waypoints", args, lease)
    assert reply["error"]["code"] == P.REFUSED
    shortest = float(reply["error"]["message"].rsplit("shortest feasible duration is ", 1)[1].split(" s")[0])
    assert shortest > 2.0
    ok(loop, sock, "waypoints", {**args, "durations_s": [shortest / 2, shortest / 2]}, lease)


@pytest.mark.parametrize("args, text", [
    ({"angles_deg": [[0, -100]], "durations_s": []}, "2 to 1000 items"),
    ({"angles_deg": [[0, -100], [1, -100]], "durations_s": [1, 2]}, "one fewer than the items of angles_deg"),
    ({"angles_deg": [[0, -100], [1, "x"]], "durations_s": [1]}, "angles_deg[1]"),
    ({"xy_mm": [[0, 0], [500, 0]], "durations_s": [5]}, "out of reach"),
    ({"angles_deg": [[0, -100], [180, -100]], "durations_s": [5]}, "outside its limits"),
    ({"angles_deg": [[0, -100], [1, -100]], "xy_mm": [[0, 1], [0, 2]], "durations_s": [1]}, "exactly one of"),
])
def test_bad_waypoints_get_a_clear_error(armed, args, text):
    loop, _, sock, lease = armed
    reply = call(loop, sock, "waypoints", args, lease)
    assert not reply["ok"] and text in reply["error"]["message"], reply


def test_a_step_sequence_holds_each_level_for_its_time(armed):
    loop, captured, sock, lease = armed
    here = [math.degrees(q) for q in loop.reference[0]]
    levels = [[here[0] + 3, here[1]], [here[0] - 2, here[1] + 1]]
    ok(loop, sock, "steps", {"angles_deg": levels, "hold_s": [8.0, 8.0]}, lease)
    run_seconds(loop, 7.9)
    assert [math.degrees(q) for q in loop.angles][0] == pytest.approx(levels[0][0], abs=0.3)
    run_seconds(loop, 8.0)
    assert [math.degrees(q) for q in loop.reference[0]] == pytest.approx(levels[1])


def test_a_level_the_rig_cannot_hold_is_refused_for_steps_and_set_alike():
    """On a rig whose bottom joint may reach -40 deg, the spring at -30 deg needs about -3.5 V
    of V_MV where -3.2 V is what a reference may ask (80 % of -4 V): a step to it is refused,
    whatever the controller could do."""
    text = config.load().source.replace("min_angle_deg = 85.0", "min_angle_deg = -40.0")
    loop, _, srv = make_loop(text, server=True)
    sock = dealer(srv)
    lease = ok(loop, sock, "lease.acquire")["lease"]
    ok(loop, sock, "enable", lease=lease)
    here = [math.degrees(q) for q in loop.reference[0]]
    reply = call(loop, sock, "steps", {"angles_deg": [[60.0, here[1]], [-30.0, here[1]]], "hold_s": [5.0, 5.0]}, lease)
    assert reply["error"]["code"] == P.REFUSED and "joint bottom" in reply["error"]["message"]
    assert "a level is beyond what the rig can hold there" in reply["error"]["message"]
    reply = call(loop, sock, "set", {"angles_deg": [-30.0, here[1]]}, lease)
    assert reply["error"]["code"] == P.REFUSED and "the rig cannot hold that angle" in reply["error"]["message"]
    ok(loop, sock, "set", {"angles_deg": [60.0, here[1]]}, lease)  # one it can hold is taken
    srv.close()


@pytest.mark.slow(seconds=3)  # a few seconds: kept out of the fast subset
def test_a_chirp_on_one_joint_moves_that_joint_and_holds_the_other(armed):
    loop, captured, sock, lease = armed
    start_cycle = loop.cycle
    here = list(loop.reference[0])
    ok(loop, sock, "excite", {"signal": "chirp", "joint": "bottom", "amplitude_deg": 1.0, "f0_hz": 0.1,
                              "f1_hz": 0.5, "duration_s": 20.0}, lease)
    run_seconds(loop, 20.0)
    n = loop.n
    rows = [(v[:n], v[n:]) for c, v in captured.series(captured.fields("measured", "position")
                                                       + captured.fields("reference", "setpoint")) if c > start_cycle]
    bottom = [math.degrees(q[0] - here[0]) for q, _ in rows]
    assert max(bottom) > 0.7 and min(bottom) < -0.7  # the loop follows the slow part of the sweep
    assert max(abs(math.degrees(r[1] - here[1])) for _, r in rows) == 0.0
    assert max(abs(math.degrees(q[1] - here[1])) for q, _ in rows) < 0.3
    assert loop.state.value == "enabled"


def test_a_prbs_starts_and_a_chirp_beyond_the_rig_is_refused_with_the_remedy(armed):
    loop, _, sock, lease = armed
    result = ok(loop, sock, "excite", {"signal": "prbs", "joint": "middle", "amplitude_deg": 0.5, "order": 6,
                                       "bit_s": 0.5}, lease)
    assert result["duration_s"] == pytest.approx(63 * 0.5)
    busy = call(loop, sock, "set", {"angles_deg": [130.0, -75.0]}, lease)  # nothing preempts a running reference
    assert busy["error"]["code"] == P.BAD_STATE and busy["error"]["data"]["reason"] == "reference_running"
    assert busy["error"]["data"]["remaining_s"] > 30.0 and loop.trajectory_name == "prbs"
    ok(loop, sock, "abort")
    reply = call(loop, sock, "excite", {"signal": "chirp", "joint": "middle", "amplitude_deg": 5.0, "f0_hz": 0.1,
                                        "f1_hz": 2.0, "duration_s": 30.0}, lease)
    assert reply["error"]["code"] == P.REFUSED
    assert "joint middle" in reply["error"]["message"] and "lower the amplitude or the top frequency" in \
        reply["error"]["message"]
    assert reply["error"]["data"]["shortfalls"][0]["joint"] == "middle" and reply["error"]["data"]["shortest_s"] is None
    for args, text in (({"signal": "sine", "joint": "bottom", "amplitude_deg": 1.0}, "one of chirp, prbs"),
                       ({"signal": "prbs", "joint": "elbow", "amplitude_deg": 1.0}, "'joint' must be one of"),
                       ({"signal": "prbs", "joint": "bottom", "amplitude_deg": 1.0, "order": 7.5}, "whole number"),
                       ({"signal": "chirp", "joint": "bottom", "amplitude_deg": 1.0, "f0_hz": 1.0, "f1_hz": 0.5},
                        "must be above"),
                       ({"signal": "prbs", "joint": "bottom", "amplitude_deg": 1.0, "f0_hz": 1.0}, "unknown argument")):
        reply = call(loop, sock, "excite", args, lease)
        assert reply["error"]["code"] == P.BAD_ARGS and text in reply["error"]["message"], reply


@pytest.mark.parametrize("overtake", ["abort", "estop", "disable", "lease.release"])
def test_a_plan_overtaken_while_it_is_prepared_is_discarded_not_started(armed, overtake):
    """Planning runs beside the loop; an abort, e-stop or disable sent meanwhile is served at
    once, and the plan that finishes after it is refused, never started. So is one whose
    client handed its lease back meanwhile (a routine interrupted by Ctrl-C while its move was
    planned): the move is no longer anyone's to start."""
    loop, _, sock, lease = armed
    control = dealer(loop.server, "control")
    rows = [[130.0 + 5.0 * math.sin(i), -75.0] for i in range(1000)]
    sock.send(P.encode_request("plan", "waypoints", {"angles_deg": rows, "durations_s": [1.0] * 999}, lease))
    for _ in range(5000):  # until the request is taken and its plan is being prepared
        loop.run(1)
        if loop.server._waiting:
            break
        sock.poll(1)
    assert loop.server._waiting, "the plan was not handed to the worker"
    args = {"who": "test"} if overtake == "estop" else {}
    (sock if overtake == "lease.release" else control).send(P.encode_request("stop", overtake, args, lease))
    replies = {}
    deadline = time.monotonic() + 120  # the plan's end is waited for: a busy machine plans slowly
    while len(replies) < 2 and time.monotonic() < deadline:
        loop.run(1)
        for s in (sock, control):
            if s.poll(0):
                reply = msgpack.unpackb(s.recv_multipart()[-1], raw=False)
                replies[reply["id"]] = reply
        if "stop" in replies:
            sock.poll(1)  # the e-stop is served; the loop idles while the worker finishes
    assert set(replies) == {"stop", "plan"}, replies
    assert replies["stop"]["ok"], replies["stop"]
    assert replies["plan"]["error"]["code"] == P.BAD_STATE, replies["plan"]
    assert loop.trajectory_name == "hold"
    loop.run(100)
    assert loop.trajectory_name == "hold" and loop.reference_remaining() == 0.0


def reference_events(captured, name: str) -> dict:
    return {e["action"]: e for e in captured.of("event") if e["kind"] == "reference" and e["name"] == name}


@pytest.mark.slow(seconds=30)
def test_a_path_starts_once_the_arm_has_settled_on_its_start_so_its_first_sample_is_not_its_worst(armed):
    """PID lags its approach to the path's start by over a degree; the path's clock starts
    only once every joint has been within 0.3 deg of the start for 0.25 s (an event says how
    long that took), so the path's worst error is the path's own, not the approach's lag."""
    loop, captured, sock, lease = armed
    result = ok(loop, sock, "path", {"name": "translation"}, lease)
    for _ in range(600):  # up to 60 s: approach, settling, the 15 s path
        run_seconds(loop, 0.1)
        if "end" in reference_events(captured, "translation"):
            break
    events = reference_events(captured, "translation")
    assert events["end"]["cut"] == ""
    settled = events.get("settled")  # when the path's clock started; straight after the approach before
    start = settled["cycle"] if settled else events["start"]["cycle"] + 1 + round(result["approach_s"] / loop.period)
    rows = [(c, [abs(math.degrees(x)) for x in e]) for c, e in captured.series(captured.fields("reference", "error"))
            if start <= c <= events["end"]["cycle"]]
    first, worst = rows[0][1], [max(e[j] for _, e in rows) for j in range(loop.n)]
    early = [max(e[j] for c, e in rows if c < start + 500) for j in range(loop.n)]  # the path's first 0.5 s
    assert all(f <= 0.3 for f in first), (first, worst)
    assert all(a < 0.8 * w for a, w in zip(early, worst)), (early, worst)
    assert settled["settled"] and 0.25 <= settled["waited_s"] < 10.0
    assert [abs(e) for e in settled["error_deg"]] == pytest.approx(first, abs=1e-6)
    schema("telemetry", "event").validate(settled)


def test_a_path_whose_joints_never_settle_starts_after_the_bounded_wait_and_says_so():
    gate = SettleGate(2.0, [0.0, 0.0], 0.001)
    off = [0.0, math.radians(0.5)]  # the middle joint held 0.5 deg off (friction, a load): never in the band
    assert all(gate.waiting(off) for _ in range(round(SETTLE_MAX_S / 0.001) - 1))
    assert not gate.waiting(off)
    assert gate.summary(off) == {"waited_s": pytest.approx(SETTLE_MAX_S), "settled": False,
                                 "error_deg": [0.0, pytest.approx(-0.5)]}
    noisy = SettleGate(2.0, [0.0], 0.001)  # in the band, out for a cycle: the settling time starts again
    assert all(noisy.waiting([0.0]) for _ in range(200)) and noisy.waiting([0.01])
    assert all(noisy.waiting([0.0]) for _ in range(249)) and not noisy.waiting([0.0])
    assert noisy.summary([0.0])["waited_s"] == pytest.approx(0.451) and noisy.settled


@pytest.mark.parametrize("elbow", [-1, 1])
@pytest.mark.parametrize("name", ["translation", "circle", "figure_eight"])
def test_a_cartesian_paths_rates_and_accelerations_move_its_tip_along_the_path(name, elbow):
    """The loop's per-cycle sample, worked out in one pass: the joint rates are those the
    arm's Jacobian maps onto the tip's velocity along the path, and the angles' own derivative;
    the accelerations the rates' own derivative (on either elbow branch, a point in each
    quarter of the path and at its cubic scaling's fastest change)."""
    rig = config.load()
    lengths = rig.arm.link_lengths_m
    make = {"translation": trajectory.translation, "circle": trajectory.circle,
            "figure_eight": trajectory.figure_eight}[name]
    path = make(lengths, elbow, len(rig.joints), 20.0)
    h = 1e-4
    for t in (0.5, 5.0, 10.0, 17.3, 19.9):
        q, qd, qdd = path.sample(t)
        (a, c), (b, d) = kinematics.jacobian(q[:2], lengths[:2])
        (x0, y0), (x1, y1) = path.tip(t - h), path.tip(t + h)
        tip_velocity = ((x1 - x0) / (2 * h), (y1 - y0) / (2 * h))
        assert (a * qd[0] + b * qd[1], c * qd[0] + d * qd[1]) == pytest.approx(tip_velocity, rel=1e-6, abs=1e-9)
        (ahead, rate_ahead, _), (behind, rate_behind, _) = path.sample(t + h), path.sample(t - h)
        assert qd == pytest.approx([(p - m) / (2 * h) for p, m in zip(ahead, behind)], rel=1e-5, abs=1e-9)
        assert qdd == pytest.approx([(p - m) / (2 * h) for p, m in zip(rate_ahead, rate_behind)], rel=1e-5, abs=1e-8)
    assert path.sample(-1.0)[2] == path.sample(21.0)[2] == [0.0] * len(rig.joints)  # at rest before and after
