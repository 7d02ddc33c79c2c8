"""Model-based controllers on the simulated rig, through the real loop on a virtual clock:
tracking targets, disturbance rejection, bumpless switches, live gains, and the designs."""
import math

import numpy as np
import pytest

from bench import scenarios as S
from controllers import registry
from controllers.base import ControllerContext, JointState, ParamError, Reference
from controllers.estimation import DelayedStateEstimator
from controllers.feasibility import Authority
from controllers.smc import sliding_hyperplane, sliding_poles
from controllers.trajectory import JointMove

HELD_TO_THE_LABS_TARGETS = ["smc", "smc_dob"]  # rig-facts §1, the thesis's best; the others: docs/controllers.md


@pytest.mark.parametrize("eps", [0.0, 2.0, 10.0])
def test_the_riccati_hyperplane_puts_every_sliding_pole_left_of_minus_eps(eps):
    s = sliding_hyperplane(2e6, 1e4, 10.0, eps)
    assert s[3] == 1.0 and s[0] < 0  # normalised on th''; z enters with the sign z' = r - th needs
    assert max(sliding_poles(s).real) < -eps


def test_the_thesis_hyperplane_is_a_stable_sliding_motion():
    s = np.array([-341.06, 32.73, 0.83, 2.34e-3])  # rig-facts §1
    assert max(sliding_poles(s).real) < 0


@pytest.mark.slow
@pytest.mark.parametrize("name", HELD_TO_THE_LABS_TARGETS)
def test_translation_path_tracks_within_the_labs_targets(name):
    loop = S.make_loop(name)
    result = S.run_path(loop, S.make_path(loop, "translation", 15.0))
    assert loop.state.value == "enabled", loop.supervisor.cause
    assert max(result.joint_max) < 3.0 and result.tip_max < 3.5, result


@pytest.mark.slow(seconds=20)
@pytest.mark.parametrize("name", HELD_TO_THE_LABS_TARGETS)
def test_the_thesis_circle_in_20_s_tracks_within_the_targets(name):
    loop = S.make_loop(name)
    result = S.run_path(loop, S.make_path(loop, "circle", 20.0))
    assert loop.state.value == "enabled", loop.supervisor.cause
    assert max(result.joint_max) < 3.0 and result.tip_max < 3.5, result


@pytest.mark.slow  # long: kept out of the fast subset
def test_the_observer_rejects_a_step_torque_faster_than_smc_alone():
    torque = S.make_loop("pid").context.models[0].kt * 1.0  # one volt's worth on the bottom joint
    plain = S.disturbance_rejection(S.make_loop("smc"), 0, torque, 10.0)
    observed = S.disturbance_rejection(S.make_loop("smc_dob"), 0, torque, 10.0)
    assert observed.peak < plain.peak and observed.recovery < plain.recovery
    assert observed.recovery < 2.0


@pytest.mark.parametrize("old,new", [("pid", "smc"), ("smc", "smc_dob"), ("smc_dob", "sac"), ("sac", "pid"),
                                     ("smc", "hold"), ("smc_dob", "lti"), ("lti", "lti_dob"), ("lti_dob", "pid")])
@pytest.mark.slow  # long: kept out of the fast subset
def test_switching_while_the_path_runs_is_bumpless_and_misses_no_cycle(old, new):
    loop = S.make_loop("hold")
    loop.switch(registry.build(old, loop.context, options=S.example_options(old)))
    path = S.make_path(loop, "translation", 15.0)
    S.approach(loop, path.sample(0.0)[0])
    loop.set_trajectory(path, "path")
    loop.run(5000)  # halfway along, moving
    before, cycle = list(loop.u), loop.cycle
    loop.switch(registry.build(new, loop.context, options=S.example_options(new)))
    loop.run(1)
    span = [hi - lo for lo, hi in zip(loop.context.u_min, loop.context.u_max)]
    assert all(abs(a - b) <= 0.01 * s for a, b, s in zip(loop.u, before, span)), (before, loop.u)
    loop.run(2000)
    assert loop.cycle == cycle + 2001 and loop.stats.overruns_total == 0
    assert loop.state.value == "enabled" and loop.controller.name == new
    if new != "hold":  # tracking continues
        assert max(abs(math.degrees(r - q)) for r, q in zip(loop.reference[0], loop.angles)) < 3.0


def test_an_estimator_told_the_applied_output_matches_one_that_was_sent_it():
    """Shadow runs: replacing the last output is the same as having advanced with it."""
    models = S.make_loop("pid").context.models
    told, sent = (DelayedStateEstimator(models, 0.001, [1e-2] * 2, [0.5] * 2) for _ in range(2))
    for est in (told, sent):
        est.reset([0.1, -1.7], [0.5, -0.5])
    rng = np.random.default_rng(1)
    for k in range(300):
        angles = [0.1 + 0.01 * math.sin(k / 50), -1.7 + 0.01 * math.cos(k / 40)]
        applied, own = rng.uniform(-3, 3, 2), rng.uniform(-3, 3, 2)
        np.testing.assert_allclose(told.estimate(angles), sent.estimate(angles), atol=1e-12)
        told.advance(own)
        told.replace_last(applied)
        sent.advance(applied)


def test_sac_told_the_applied_output_feeds_its_pfc_with_it():
    """Shadow runs: after applied(u) the PFC and washout states are those the module's
    equations give for u, not for SAC's own output."""
    ctx = S.make_loop("pid").context
    sac = registry.build("sac", ctx)
    angles = [2.2, -1.6]
    sac.reset(JointState(0.0, angles, [0.0, 0.0]), [0.5, -0.5])
    rng = np.random.default_rng(2)
    for k in range(200):
        mean, xf = list(sac._u_mean), list(sac._xf)
        ref = Reference([a + 0.01 * math.sin(k / 30) for a in angles], [0.0, 0.0], [0.0, 0.0])
        own = sac.step(JointState(k * ctx.dt, angles, [0.0, 0.0]), ref)
        real = list(rng.uniform(-3, 3, 2))
        sac.applied(real)
        c = sac.k
        for j in range(2):
            m = c.aw[j] * mean[j] + (1 - c.aw[j]) * real[j]
            assert sac._u_mean[j] == pytest.approx(m, rel=1e-12, abs=1e-12)
            assert sac._xf[j] == pytest.approx(c.af[j] * xf[j] + (1 - c.af[j]) * c.kf[j] * (real[j] - m),
                                               rel=1e-9, abs=1e-15)
        assert own != real


def test_a_live_gain_change_acts_next_cycle_and_a_bad_one_changes_nothing():
    loop = S.make_loop("smc")
    loop.run(2000)
    target = list(loop.reference[0])
    target[0] += math.radians(0.3)  # small enough that the output is not at a limit 20 cycles on
    loop.set_trajectory(JointMove(loop.reference[0], target, 0.0), "step")
    loop.run(20)
    params = loop.controller.get_params()
    with pytest.raises(ParamError, match=r"switch_volts\[bottom\] = 99.0 V is outside 0.0..10.0 V"):
        loop.controller.set_params({"switch_volts": [99.0, 1.0]})
    with pytest.raises(ParamError, match="q_z"):
        loop.controller.set_params({"q_z": [2e6, "x"]})
    assert loop.controller.get_params() == params
    twin = S.make_loop("smc")  # the same run, but with the reaching term off from this cycle on
    twin.run(2000)
    twin.set_trajectory(JointMove(twin.reference[0], target, 0.0), "step")
    twin.run(20)
    assert twin.u == loop.u
    twin.controller.set_params({"reach_rate": [0.0, 0.0]})
    loop.run(1)
    twin.run(1)
    assert twin.u[0] != pytest.approx(loop.u[0], abs=1e-3)


def test_a_model_based_controller_without_an_identified_model_is_refused_clearly():
    ctx = S.make_loop("pid").context
    bare = ControllerContext(ctx.joint_names, ctx.dt, ctx.u_min, ctx.u_max, (ctx.models[0], None))
    with pytest.raises(ParamError, match=r"smc needs an identified model for joint\(s\) middle"):
        registry.build("smc", bare)


@pytest.mark.parametrize("fraction", [1.0, 0.8])
def test_feasibility_finds_the_shortest_duration_exactly(fraction):
    loop = S.make_loop("pid")
    auth = Authority.of(loop.rig, loop.context, fraction)
    make = lambda d: S.make_path(loop, "circle", d)  # noqa: E731
    shortest = S.shortest_feasible(loop, "circle", fraction)
    assert not auth.shortfalls(make(shortest))
    assert auth.shortfalls(make(shortest - 0.2))
    # the margin asks for more time than the whole range does
    assert S.shortest_feasible(loop, "translation", fraction) >= S.shortest_feasible(loop, "translation")


def test_the_built_in_rig_runs_the_thesis_paths_at_the_thesis_durations_keeping_a_fifth_of_v_mv_for_feedback():
    """Issue 32: the lab ran the translation in 15 s and the circle in 20 s with every
    controller; the reconstructed rig accepts both with the margin the daemon keeps."""
    loop = S.make_loop("pid")
    assert loop.rig.limits.authority_fraction == 0.8
    auth = S.authority(loop)
    for name, thesis_s in (("translation", 15.0), ("circle", 20.0)):
        assert not auth.shortfalls(S.make_path(loop, name, thesis_s)), name
        shortest = S.shortest_feasible(loop, name, 0.8)
        assert S.shortest_feasible(loop, name) < shortest < thesis_s  # the margin costs time, not the thesis's


@pytest.mark.parametrize("joint", [0, 1])
@pytest.mark.parametrize("pfc_gain_deg_per_volt", [0.5, 2.5])
def test_the_pfc_keeps_the_augmented_plant_aspr_at_the_default_and_the_thesis_gain(joint, pfc_gain_deg_per_volt):
    """G + H is ASPR when H^-1 = (tau_f s + 1)/k_f stabilises the nominal plant [2-43]: the
    roots of (J s^2 + D s + K)(T_ep s + 1) k_f + kt (tau_f s + 1) are all in the left half."""
    ctx = S.make_loop("pid").context
    m, sac = ctx.models[joint], registry.build("sac", ctx)
    k_f, tau_f = math.radians(pfc_gain_deg_per_volt), sac.p("pfc_tau")[joint]
    plant = np.polymul([m.J, m.D, m.K], [m.T_ep, 1.0]) * k_f
    closed = np.polyadd(plant, [m.kt * tau_f, m.kt])
    assert max(np.roots(closed).real) < 0


@pytest.mark.slow  # long: kept out of the fast subset
def test_sac_holds_the_middle_joint_against_a_torque_step_without_stick_slip_hunting():
    """With the dead zone on its adaptation SAC's middle joint stays within 0.5 deg of its
    set-point against a torque step, on Karnopp's stiction (the rig-file option for stick-slip
    studies). On the first built-in rig it hunted by +-0.6 deg without the dead zone; on the
    reconstructed rig (issue 32: a middle loop 7.5 times as fast) it no longer does at this
    torque, so the scenario shows the hold, not the hunting."""
    torque = S.make_loop("pid").context.models[1].kt * 1.0
    karnopp = {"friction_model": "karnopp"}
    held = S.disturbance_rejection(S.make_loop("sac", plant=karnopp), 1, torque, 20.0)
    assert held.peak < 0.5 and held.recovery == 0.0
