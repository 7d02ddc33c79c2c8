"""A known payload fed forward (controllers.known_load, daemon.loop.feed_forward, ``load.set``):
its volts balance the payload's moment, the loaded arm holds closer with it, setting and
clearing it does not bump the output, the planner counts it against the joints' range, and
loads the arm cannot carry are refused with the reason."""
from __future__ import annotations

import dataclasses
import math

import msgpack
import numpy as np
import pytest

from bench.payload import rig_text
from controllers.known_load import KnownLoad
from daemon.wire import protocol as P
from hal import config
from hal.kinematics import payload_torques
from daemon.testing.loop import call, dealer, exchange, make_loop, ok, run_seconds
from daemon.testing.simrig import make_rig

TRUE_PAYLOAD = (0.3, (20.0, -10.0))  # the simulated arm's [kg], [mm]: more than friction holds


def _load(sim, mass_kg, com_mm):
    arm = sim.rig.arm
    return KnownLoad.for_rig(mass_kg, [c * 1e-3 for c in com_mm], sim.context(), arm.link_lengths_m,
                             arm.gravity_m_s2)


def test_the_feed_forward_balances_the_payloads_moment_at_every_posture():
    sim = make_rig()
    load = _load(sim, 0.2, (30.0, 5.0))
    rng = np.random.default_rng(1)
    q = rng.uniform(-math.pi, math.pi, size=(50, 2))
    along = load.volts_along(q)
    for row, planned in zip(q, along):
        volts = load.volts(row)
        torques = payload_torques(row, sim.rig.arm.link_lengths_m, 0.2, (0.03, 0.005), sim.rig.arm.gravity_m_s2)
        for u, tau, model in zip(volts, torques, sim.context().models):
            assert model.kt * u == pytest.approx(-tau, abs=1e-12)  # the cylinders' torque holds the payload
        assert planned == pytest.approx(volts, abs=1e-12)  # the planner's array form is the same model
    assert np.abs(along).max() > 0.5  # volts a test can see


def test_loads_the_arm_cannot_carry_or_cannot_be_computed_are_refused_with_the_reason():
    sim = make_rig()
    with pytest.raises(ValueError, match=r"needs up to .* on joint middle, beyond its range"):
        _load(sim, 0.5, (20.0, 0.0))
    with pytest.raises(ValueError, match="centre of mass 600 mm from the tip"):
        _load(sim, 0.1, (600.0, 0.0))
    context = sim.context()
    unmodelled = dataclasses.replace(context, models=(context.models[0], None))  # a joint not yet identified
    with pytest.raises(ValueError, match=r"joint\(s\) middle have no identified model"):
        KnownLoad.for_rig(0.1, (0.0, 0.0), unmodelled, sim.rig.arm.link_lengths_m, sim.rig.arm.gravity_m_s2)


def _hold_error_after_enable(load) -> float:
    """The loaded arm (the simulator's TRUE_PAYLOAD) enabled under PID with ``load`` given
    (or none): the middle joint's mean |error| [deg] over the last 0.5 s of the 3 s after."""
    loop, _, srv = make_loop(rig_text(*TRUE_PAYLOAD), server=True)
    try:
        sock = dealer(srv)
        lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
        if load is not None:
            ok(loop, sock, "load.set", {"mass_kg": load[0], "com_mm": list(load[1])}, lease)
        ok(loop, sock, "enable", lease=lease)
        errors = []
        for _ in range(3000):
            loop.run(1)
            errors.append(abs(math.degrees(loop.angles[1] - loop.reference[0][1])))
        return float(np.mean(errors[-500:]))
    finally:
        srv.close()


@pytest.mark.slow
def test_the_loaded_arm_holds_closer_with_its_load_fed_forward_even_an_estimated_one():
    without = _hold_error_after_enable(None)
    exact = _hold_error_after_enable(TRUE_PAYLOAD)
    estimated = _hold_error_after_enable((0.26, (15.0, 0.0)))  # off by 13 % and 11 mm
    assert without > 0.5, without  # the integrator still winding up against the payload
    assert exact < 0.3 * without, (exact, without)
    # an estimate off by 13 % and 11 mm still halves it (on 150 mm links the estimate's error
    # is a larger torque than on the first built-in's 100 mm, issue 32)
    assert estimated < 0.6 * without, (estimated, without)


def _largest_step(loop, sock, cmd, args, lease):
    """``cmd``'s reply, and the largest change of any joint's V_MV from one cycle to the next
    over the cycles the exchange ran and the one after [V]: a bump shows as one cycle's step,
    where the arm's own drift over a reply's (real-time dependent) wait does not."""
    last, steps = [list(loop.u)], []

    def watch():
        steps.append(max(abs(now - was) for now, was in zip(loop.u, last[0])))
        last[0] = list(loop.u)
    reply = exchange(loop, sock, P.encode_request(9001, cmd, args, lease), each_cycle=watch)
    assert reply is not None and reply["ok"], reply
    loop.run(1)
    watch()
    return reply["result"], max(steps)


def test_setting_and_clearing_a_load_is_bumpless_reported_and_planned_with():
    loop, captured, srv = make_loop(rig_text(*TRUE_PAYLOAD), server=True)
    try:
        sock = dealer(srv)
        lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
        ok(loop, sock, "enable", lease=lease)
        run_seconds(loop, 1.0)
        reply, step = _largest_step(loop, sock, "load.set", {"mass_kg": 0.3, "com_mm": [20.0, 0.0]}, lease)
        ff = reply["load"]["feedforward_volts"]
        assert reply["load"]["mass_kg"] == 0.3 and reply["load"]["com_mm"] == pytest.approx([20.0, 0.0])
        assert abs(ff["middle"]) > 1.0  # a feed-forward the bump would show
        assert step < 0.05  # the controller took over the difference
        status = ok(loop, sock, "status")
        assert status["load"]["feedforward_volts"]["middle"] == pytest.approx(ff["middle"], abs=0.05)

        # the planner counts the load: raising the middle joint to -43 deg (its limit less the set-point
        # margin) in 4.8 s is within its usable V_MV unloaded, not with the volts that hold 0.3 kg (5.3 s)
        target = {"angles_deg": [math.degrees(loop.reference[0][0]), -43.0], "duration_s": 4.8}
        refused = call(loop, sock, "set", target, lease)
        assert not refused["ok"] and refused["error"]["code"] == P.REFUSED, refused
        assert refused["error"]["data"]["shortfalls"][0]["joint"] == "middle"

        reply, step = _largest_step(loop, sock, "load.clear", None, lease)
        assert reply["cleared"] is True and step < 0.05
        assert ok(loop, sock, "status")["load"] is None
        assert ok(loop, sock, "load.clear", lease=lease)["cleared"] is False
        assert ok(loop, sock, "set", target, lease)["duration_s"] == 4.8
        kinds = [(m["kind"], m.get("action")) for m in captured.of("event") if m["kind"] == "load"]
        assert kinds == [("load", "set"), ("load", "clear")]
    finally:
        srv.close()


@pytest.mark.parametrize("args, argument", [
    ({"mass_kg": 0.6}, "mass_kg"),
    ({"mass_kg": 0.0}, "mass_kg"),
    ({"mass_kg": float("nan")}, "mass_kg"),
    ({"mass_kg": 0.1, "com_mm": [1e4, 0.0]}, "com_mm"),
    ({"mass_kg": 0.1, "com_mm": "here"}, "com_mm"),
    ({"mass_kg": 0.1, "com_mm": [1.0, 2.0, 3.0]}, "com_mm"),
    ({"mass_kg": 0.1, "unit": "lb"}, "unit"),
])
def test_a_bad_load_gets_a_clear_refusal_naming_its_argument_and_changes_nothing(args, argument):
    loop, _, srv = make_loop(server=True)
    try:
        sock = dealer(srv)
        lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
        reply = call(loop, sock, "load.set", args, lease)
        assert not reply["ok"] and reply["error"]["code"] == P.BAD_ARGS, reply
        assert reply["error"]["data"]["argument"] == argument
        assert loop.feed_forward.load is None
    finally:
        srv.close()


def test_the_built_in_rigs_all_take_a_load_within_their_capacity():
    for name in ("sim", "sim-3joint"):
        rig = config.load(name)
        sim = make_rig(name=name)
        load = _load(sim, 0.1, (10.0, 0.0))
        assert len(load.volts([math.radians(j.neutral_deg) for j in rig.joints])) == len(rig.joints)


def test_an_input_experiment_is_planned_about_the_volts_that_hold_the_known_load():
    """The payload routine dithers with a load possibly set: the open-loop operating point the
    planner checks against the V_MV range includes the load's holding volts."""
    from daemon.planner import commands as planner

    sim = make_rig()
    plain = planner.PlanContext.of(sim.rig, sim.context())
    load = _load(sim, 0.3, (20.0, 0.0))
    loaded = dataclasses.replace(plain, authority=dataclasses.replace(plain.authority, load=load))
    setpoint = [math.radians(120.0), math.radians(-100.0)]
    args = {"side": "input", "signal": "multisine", "joint": "middle", "amplitude_v": 0.5, "f0_hz": 0.5,
            "f1_hz": 1.0, "components": 1, "period_s": 2.0, "periods": 2}
    request = {"cmd": "excite", "payload": msgpack.packb(args), "args_span": (0, len(msgpack.packb(args))), "id": 1}
    without = planner.plan(plain, request, setpoint, 0).reply["u_op_estimate_v"]
    with_load = planner.plan(loaded, request, setpoint, 0).reply["u_op_estimate_v"]
    assert with_load - without == pytest.approx(load.volts(setpoint)[1], abs=1e-9)
    assert with_load - without > 2.0
