"""Set-points keep the rig file's margin inside the joint limits ([safety] setpoint_margin_deg,
setpoint_margin_mm; daemon/planner/commands.py check_limits): one at or near a limit is refused,
naming the margin, since a controller's overshoot past it would trip the arm; one at the margin
runs without a trip. And on the linear axis, a recovery from outside its limits moves it inward
(daemon/loop/recovery.py), on the real loop on a virtual clock."""
import math

import pytest

from daemon.testing.loop import call, dealer, make_loop, ok, run_seconds
from hal import config
from tests.schemas import schema


@pytest.fixture
def axis():
    loop, captured, srv = make_loop(rig_text=config.load("sim-axis").source, server=True, controller="axis_pid")
    sock = dealer(srv)
    lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
    ok(loop, sock, "enable", lease=lease)
    run_seconds(loop, 0.5)
    yield loop, captured, sock, lease
    srv.close()


def lowest_while_enabled(loop, seconds: float) -> float:
    """The lowest position [SI] over ``seconds`` of cycles, stopping at a trip."""
    low = math.inf
    for _ in range(int(round(seconds / loop.period))):
        loop.run(1)
        low = min(low, loop.angles[0])
        if loop.state.value != "enabled":
            break
    return low


@pytest.mark.slow(seconds=20)
def test_a_set_point_at_the_axis_limit_is_refused_naming_the_margin_and_one_at_the_margin_runs(axis):
    loop, _, sock, lease = axis
    joint = ok(loop, sock, "describe")["joints"][0]  # a client reads the range it may ask for
    assert (joint["position_unit"], joint["setpoint_range"]) == ("mm", [15.0, 185.0])
    for position in (10.0, 14.9):  # the limit (a step there overshot and tripped), and inside the margin
        refused = call(loop, sock, "set", {"positions": [position], "duration_s": 0.0}, lease)
        assert refused["error"]["code"] == "refused", refused
        message, data = refused["error"]["message"], refused["error"]["data"]
        assert "within 5 mm of its limits 10.0..190.0 mm" in message and "setpoint_margin_mm" in message
        assert "so 15.0..185.0 mm" in message
        assert data == {"reason": "limits", "joint": "axis", "position_mm": pytest.approx(position),
                        "limits_mm": [10.0, 190.0], "margin_mm": 5.0}
        schema("error-data").validate(data)
    assert call(loop, sock, "set", {"positions": [195.0], "duration_s": 0.0}, lease)["error"]["message"] == \
        "joint axis set-point 195.00 mm is outside its limits 10.0..190.0 mm"  # outside: said as before
    ok(loop, sock, "set", {"positions": [15.0], "duration_s": 1.0}, lease)  # 90 mm in 1 s, at up to 135 mm/s
    low = lowest_while_enabled(loop, 4.0)
    assert loop.state.value == "enabled", loop.supervisor.cause
    assert 10.0 < low * 1e3 < 15.0 and loop.angles[0] * 1e3 == pytest.approx(15.0, abs=0.5)  # overshot, inside


@pytest.mark.slow(seconds=30)
def test_a_set_point_near_a_rotary_limit_is_refused_naming_the_margin_and_one_at_the_margin_runs():
    loop, _, srv = make_loop(server=True)
    try:
        sock = dealer(srv)
        lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
        ok(loop, sock, "enable", lease=lease)
        run_seconds(loop, 0.5)
        described = ok(loop, sock, "describe")
        schema("results", "describe").validate(described)
        assert [(j["position_unit"], j["setpoint_range"]) for j in described["joints"]] == \
            [("deg", pytest.approx([88.0, 172.0])), ("deg", pytest.approx([-157.0, -43.0]))]
        refused = call(loop, sock, "set", {"angles_deg": [174.0, -62.0], "duration_s": 5.0}, lease)
        assert refused["error"]["code"] == "refused"
        assert refused["error"]["message"] == (
            "joint bottom set-point 174.00 deg is within 3 deg of its limits 85.0..175.0 deg: set-points keep "
            "3 deg inside (the rig file's [safety] setpoint_margin_deg), so 88.0..172.0 deg")
        assert refused["error"]["data"]["margin_deg"] == 3.0
        steps = call(loop, sock, "steps", {"angles_deg": [[140.0, -100.0], [140.0, -158.0]], "hold_s": [1.0, 1.0]},
                     lease)
        assert "joint middle set-point -158.00 deg is within 3 deg" in steps["error"]["message"]
        ok(loop, sock, "set", {"angles_deg": [172.0, -62.0], "duration_s": 5.0}, lease)  # 30 deg in 5 s
        run_seconds(loop, 8.0)
        assert loop.state.value == "enabled", loop.supervisor.cause
        assert [math.degrees(a) for a in loop.angles] == pytest.approx([172.0, -62.0], abs=1.0)
    finally:
        srv.close()


def test_the_margin_is_a_rig_file_key_checked_against_the_joint_range():
    rig = config.load("sim")
    assert (rig.safety.setpoint_margin_deg, rig.safety.setpoint_margin_mm) == (3.0, 5.0)
    assert rig.setpoint_margins == pytest.approx((math.radians(3.0),) * 2)
    assert config.load("sim-axis").setpoint_margins == pytest.approx((0.005,))
    text = rig.source.replace("[safety]\n", "[safety]\nsetpoint_margin_deg = 45.0\n", 1)
    with pytest.raises(config.ConfigError, match=r"safety\.setpoint_margin_deg: 45\.0 leaves joint bottom no "
                                                   r"set-point inside its limits 85\.0\.\.175\.0 deg"):
        config.parse(text)


@pytest.mark.slow(seconds=30)
def test_the_axis_enabled_outside_its_limit_is_moved_inward_and_not_tripped(axis):
    """Pushed 1.5 mm out past its 10 mm limit while vented, the axis is enabled: the recovery
    move takes it inward, in mm (2 mm inside, the further-out rule 1 mm), without a trip."""
    loop, captured, sock, lease = axis
    ok(loop, sock, "set", {"positions": [15.0], "duration_s": 2.0}, lease)
    run_seconds(loop, 3.0)
    ok(loop, dealer(loop.server, "control"), "estop", {"who": "test"})
    arm = loop.io.transport.arm
    arm.disturbance_n[0] = -40.0  # a hand pushing it out, then let go
    while loop.angles[0] > 0.0085:
        run_seconds(loop, 0.01)
    arm.disturbance_n[0] = 0.0
    run_seconds(loop, 1.0)
    ok(loop, sock, "lease.renew", lease=lease)
    ok(loop, sock, "reset", lease=lease)
    start = loop.angles[0]
    assert start * 1e3 < 10.0
    recover = ok(loop, sock, "enable", lease=lease)["recover"]
    assert recover["joints"]["axis"]["target_mm"] == pytest.approx(12.0)
    low = lowest_while_enabled(loop, recover["within_s"] + 1.0)
    assert loop.state.value == "enabled", loop.supervisor.cause
    assert low > start - 0.001 and loop.angles[0] * 1e3 == pytest.approx(12.0, abs=1.0)  # inward, to the target
    assert [e["action"] for e in captured.of("event") if e["kind"] == "recover"] == ["start", "done"]
