"""The way back after a trip: vented, a joint sags outside its limits (its load, its spring);
``reset`` + ``enable`` then moves it back inside (daemon/loop/recovery.py) instead of tripping
at once, and trips if it goes further out or does not come back in time. And the built-in
rigs' vented rest, which docs/simulator.md states."""
import math
from pathlib import Path

import pytest

from daemon.loop.recovery import (RECOVER_GRACE_S, RECOVER_MARGIN_DEG, RECOVER_MIN_S, RECOVER_SPEED_DEG_S,
                                   Recovery)
from daemon.testing.loop import call, dealer, make_loop, ok, run_seconds
from hal import config
from hal.regulator import ITV0051
from sim_backend.plant import SimArm, regulator_output
from sim_backend.options import SimOptions
from tests.schemas import schema

MIDDLE = 1
SAG_NM = -0.15  # a load pulling the middle joint down, past its -160 deg limit onto its end stop (-170 deg)
DOCS = Path(__file__).resolve().parents[1] / "docs"


def sagged(loop, sock, lease, load_nm: float = SAG_NM) -> float:
    """Vented by an e-stop, the middle joint pulled by ``load_nm`` until it rests on its end
    stop, 10 deg outside its limit (the lease renewed meanwhile); its angle [deg]."""
    ok(loop, dealer(loop.server, "control"), "estop", {"who": "test"})
    loop.io.transport.arm.disturbance_nm[MIDDLE] = load_nm
    for _ in range(30):
        run_seconds(loop, 1.0)
        ok(loop, sock, "lease.renew", lease=lease)
        if math.degrees(loop.angles[MIDDLE]) < -169.5:
            break
    return math.degrees(loop.angles[MIDDLE])


def events(captured, kind: str) -> list[dict]:
    return [e for e in captured.of("event") if e["kind"] == kind]


@pytest.fixture
def served():
    loop, captured, srv = make_loop(server=True)
    sock = dealer(srv)
    lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
    ok(loop, sock, "enable", lease=lease)
    run_seconds(loop, 1.0)
    yield loop, captured, sock, lease
    srv.close()


@pytest.mark.slow(seconds=20)
def test_an_arm_that_sagged_outside_its_limits_after_an_estop_is_enabled_back_inside_and_then_moves(served):
    loop, captured, sock, lease = served
    angle = sagged(loop, sock, lease)  # the load stays on, as gravity would
    assert angle < -169.0 and loop.state.value == "estop"
    assert ok(loop, sock, "reset", lease=lease) == {"state": "idle"}
    enabled = ok(loop, sock, "enable", lease=lease)
    run_seconds(loop, 0.1)
    assert loop.state.value == "enabled", loop.supervisor.cause  # not tripped again at once by the limit rule
    assert enabled["state"] == "enabled"
    recover = enabled["recover"]
    assert list(recover["joints"]) == ["middle"]
    middle = recover["joints"]["middle"]
    assert middle["angle_deg"] == pytest.approx(angle, abs=0.2) and middle["limits_deg"] == [-160.0, -40.0]
    assert middle["target_deg"] == pytest.approx(-160.0 + RECOVER_MARGIN_DEG)
    assert recover["move_s"] == pytest.approx(max(RECOVER_MIN_S, (middle["target_deg"] - middle["angle_deg"])
                                                  / RECOVER_SPEED_DEG_S))
    assert recover["within_s"] == pytest.approx(recover["move_s"] + RECOVER_GRACE_S)
    schema("results", "enable").validate(enabled)
    assert loop.trajectory_name == "recover"
    refused = call(loop, sock, "set", {"angles_deg": [141.0, -120.0], "duration_s": 5.0}, lease)
    assert refused["error"]["code"] == "bad_state" and "(recover) is running" in refused["error"]["message"]
    run_seconds(loop, recover["within_s"] + 1.0)
    assert loop.state.value == "enabled", loop.supervisor.cause
    start, done = events(captured, "recover")
    assert start["action"] == "start" and done["action"] == "done" and done["after_s"] < recover["within_s"]
    for event in (start, done):
        schema("telemetry", "event").validate(event)
    assert -160.0 < math.degrees(loop.angles[MIDDLE]) < -157.0  # held inside, against the load
    ok(loop, sock, "lease.renew", lease=lease)
    ok(loop, sock, "set", {"angles_deg": [141.0, -120.0], "duration_s": 5.0}, lease)
    run_seconds(loop, 8.0)
    assert loop.state.value == "enabled", loop.supervisor.cause
    assert [math.degrees(a) for a in loop.angles] == pytest.approx([141.0, -120.0], abs=1.0)


def test_a_joint_enabled_outside_its_limits_trips_if_it_is_not_back_in_time_and_noise_at_the_limit_is_no_trip():
    names, limits, dt = ("bottom", "middle"), [(math.radians(85.0), math.radians(175.0)),
                                               (math.radians(-160.0), math.radians(-40.0))], 0.001
    at = [math.radians(140.0), math.radians(-165.0)]
    stuck = Recovery(names, limits, at, dt)
    assert stuck.limits[0] == limits[0] and stuck.limits[1] == (-math.inf, math.inf)  # the usual rule, but not there
    assert stuck.targets == [at[0], pytest.approx(math.radians(-160.0 + RECOVER_MARGIN_DEG))]
    held = [at[0], math.radians(-164.0)]  # on its way, never in
    cycles = round(stuck.within_s / dt)
    assert all(stuck.check(held) is None for _ in range(cycles))
    cause = stuck.check(held)
    assert cause == (f"joint middle enabled outside its limits is not back inside within {stuck.within_s:.1f} s: "
                     f"at -164.0 deg, enabled at -165.0 deg (limits -160.0..-40.0 deg)")
    noisy = Recovery(names, limits, at, dt)  # just inside, then out again by noise: still on its way
    for angle in (-159.5, -160.2, -159.3, -158.9):
        assert noisy.check([at[0], math.radians(angle)]) is None
    assert noisy.finished and noisy.limits == limits  # 1 deg inside: back, its limit the usual one again
    assert Recovery(names, limits, [at[0], math.radians(-100.0)], dt).finished  # inside: nothing to recover


@pytest.mark.slow(seconds=20)
def test_a_joint_enabled_outside_its_limits_that_goes_further_out_trips(served):
    loop, captured, sock, lease = served
    ok(loop, dealer(loop.server, "control"), "estop", {"who": "test"})
    loop.io.transport.arm.disturbance_nm[MIDDLE] = SAG_NM
    while math.degrees(loop.angles[MIDDLE]) > -163.0:
        run_seconds(loop, 0.05)
    loop.io.transport.arm.disturbance_nm[MIDDLE] = 0.0  # at rest outside its limit, short of its end stop
    run_seconds(loop, 1.0)
    ok(loop, sock, "lease.renew", lease=lease)
    ok(loop, sock, "reset", lease=lease)
    angle = math.degrees(loop.angles[MIDDLE])
    ok(loop, sock, "enable", lease=lease)
    loop.io.transport.arm.disturbance_nm[MIDDLE] = -1.5  # more than the cylinder's 0.8 N m: pulled out further
    for _ in range(100):
        run_seconds(loop, 0.02)
        if loop.state.value != "enabled":
            break
    assert loop.state.value == "fault"
    cause = loop.supervisor.cause
    assert cause.startswith("joint middle enabled outside its limits went further out: ")
    enabled_at = float(cause.split("enabled at ")[1].split(" deg")[0])
    tripped_at = float(cause.split("further out: ")[1].split(" deg")[0])
    assert enabled_at == pytest.approx(angle, abs=0.2)
    assert enabled_at - 1.2 <= tripped_at <= enabled_at - 0.9  # at the first sample 1 deg further out
    assert [e["action"] for e in events(captured, "recover")] == ["start"]


def vented_rest_deg(rig) -> list[float]:
    """Where each joint of a cylinder rig comes to rest vented, by its simulated plant: the
    spring's balance at the safe pressures (the identified friction holds nothing, so it gets
    there, slowly), within the end stops."""
    arm = SimArm(rig, SimOptions())
    out = []
    for jc, joint in zip(rig.joints, arm.joints):
        head, rod = (regulator_output(ITV0051(c).volts(c.safe_mpa * 1e6), arm.supply_pa) for c in (jc.head, jc.rod))
        out.append(min(max(joint.equilibrium_deg(head, rod), joint.stop_lo), joint.stop_hi))
    return out


def test_the_built_in_rigs_vented_rest_is_where_the_simulator_document_says():
    text = " ".join((DOCS / "simulator.md").read_text().split())  # the phrases across line breaks
    rests = {name: vented_rest_deg(config.load(name)) for name in ("sim", "sim-3joint")}
    assert [round(a, 1) for a in rests["sim"]] == [120.1, -165.8]
    assert [round(a, 1) for a in rests["sim-3joint"]] == [120.1, -165.8, -55.0]
    for phrase in ("bottom joint 120.1 deg", "middle joint -165.8 deg", "top joint -55.0 deg"):
        assert phrase in text
