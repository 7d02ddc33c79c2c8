"""The simulated joint is the identified model of rig-facts §1, checked against scipy.

With friction off, the response from V_MV to the joint angle must be the transfer function
[2-50] with its dead time; it is checked two independent ways: the continuous step response
from partial fractions (any dead time, fractional included), and scipy's own ZOH
discretisation with the dead time as whole samples.
"""
import math

import numpy as np
import pytest
from scipy import signal

from hal.identified import IDENTIFIED, K_EP, P_OFFSET
from hal.joint_model import JointModel
from daemon.testing.simrig import make_rig

H = 0.001
V_INI = 4.0


def pset(volts):
    return K_EP * volts + P_OFFSET


def transfer_function(p):
    """[2-50] without the dead time: K_mdl L A_H K_ep / ((J s^2 + D s + K)(T_ep s + 1)) [deg/V]."""
    num = [p.K_mdl * p.L * p.area_head * K_EP]
    den = np.polymul([p.J, p.D, p.K], [p.T_ep, 1.0])
    return num, den


def joint_at_rest(p, friction=False, dead_time=True, friction_model="stribeck"):
    bias = (pset(V_INI), pset(V_INI))
    j = JointModel(p, H, neutral_deg=0.0, stops_deg=(-1e3, 1e3), initial_deg=0.0, initial_pset=bias,
                   friction=friction, dead_time=dead_time, friction_model=friction_model)
    j.th = j.equilibrium_deg(*bias)
    return j


def step_response(joint, dv, n):
    """Angle change [deg] at samples 1..n after V_MV steps by dv at t = 0."""
    th0 = joint.th
    out = []
    for _ in range(n):
        joint.step(pset(V_INI + dv), pset(V_INI))
        out.append(joint.th - th0)
    return np.array(out)


def analytic_step(num, den, t):
    """Continuous unit-step response from partial fractions of G(s)/s (distinct poles)."""
    r, poles, _ = signal.residue(num, np.polymul(den, [1.0, 0.0]))
    y = np.zeros_like(t)
    positive = t > 0
    for ri, pi in zip(r, poles):
        y[positive] += np.real(ri * np.exp(pi * t[positive]))
    return y


@pytest.mark.parametrize("name", ["bottom", "middle"])
def test_step_matches_transfer_function_with_fractional_dead_time(name):
    p = IDENTIFIED[name]
    n = 6000
    y = step_response(joint_at_rest(p), 1.0, n)
    t = np.arange(1, n + 1) * H
    expected = analytic_step(*transfer_function(p), t - p.T_dly)
    final = p.torque_per_volt / p.K  # steady-state gain [deg/V], the scale of the tolerance
    assert expected[-1] > 0.2 * final  # the comparison covers a large part of the rise
    assert np.max(np.abs(y - expected)) < 1e-9 * final


@pytest.mark.parametrize("name", ["bottom", "middle"])
def test_step_matches_scipy_zoh_discretisation_with_whole_sample_delay(name):
    p = IDENTIFIED[name].replace({"T_dly": 0.040})
    num, den = transfer_function(p)
    ad, bd, cd, dd, _ = signal.cont2discrete(signal.tf2ss(num, den), H, method="zoh")
    n = 3000
    u = np.ones(n + 1)
    u_delayed = np.concatenate([np.zeros(40), u])[: n + 1]
    _, yd, _ = signal.dlsim((ad, bd, cd, dd, H), u_delayed)
    y = step_response(joint_at_rest(p), 1.0, n)
    final = p.torque_per_volt / p.K
    assert np.max(np.abs(y - yd.ravel()[1:])) < 1e-8 * final


def test_dead_time_is_exact_in_samples():
    p = IDENTIFIED["bottom"].replace({"T_dly": 0.040})
    y = step_response(joint_at_rest(p), 1.0, 100)
    assert np.all(np.abs(y[:40]) < 1e-12)  # samples 1..40: the input has not arrived
    assert y[40] > 1e-9  # sample 41: it has acted for one step
    # the identified 81.17 ms: still at rest at 81 ms, moving at 82 ms
    y = step_response(joint_at_rest(IDENTIFIED["bottom"]), 1.0, 100)
    assert np.all(np.abs(y[:81]) < 1e-12) and y[81] > 1e-12


def test_without_dead_time_the_response_starts_at_once():
    y = step_response(joint_at_rest(IDENTIFIED["bottom"], dead_time=False), 1.0, 3)
    assert y[0] > 0


@pytest.mark.parametrize("name", ["bottom", "middle"])
def test_regulator_lag_has_the_identified_time_constant(name):
    p = IDENTIFIED[name]
    joint = joint_at_rest(p)
    p0, p1 = pset(V_INI), pset(V_INI + 2.0)
    t = np.arange(1, 401) * H
    pressures = []
    for _ in t:
        joint.step(p1, p0)
        pressures.append(joint.p_head)
    expected = p0 + (p1 - p0) * np.clip(1 - np.exp(-(t - p.T_dly) / p.T_ep), 0, None)
    assert np.max(np.abs(np.array(pressures) - expected)) < 1e-6 * (p1 - p0)
    assert joint.p_rod == pytest.approx(p0)


@pytest.mark.parametrize("name", ["bottom", "middle"])
def test_karnopp_friction_sticks_below_breakaway_and_slips_above(name):
    p = IDENTIFIED[name]
    for fraction, moves in ((0.9, False), (1.15, True)):
        joint = joint_at_rest(p, friction=True, friction_model="karnopp")
        dv = fraction * p.Fs / p.torque_per_volt  # extra torque = fraction * Fs once the lag settles
        y = step_response(joint, dv, 3000)
        if moves:
            assert y[-1] > 1.0, f"{name}: {fraction} Fs should break away"
        else:
            assert np.all(y == 0.0), f"{name}: {fraction} Fs should stick"
            assert joint.w == 0.0


def stribeck(p, w):
    """[2-45]'s Coulomb/Stribeck part with the smooth sign [N m] at velocity w [model units/s]."""
    return (p.Fc + (p.Fs - p.Fc) * np.exp(-(np.abs(w) / p.vs) ** p.alpha)) * np.tanh(p.beta * w / p.vs)


@pytest.mark.parametrize("name", ["bottom", "middle"])
def test_the_identified_smooth_friction_creeps_in_balance_below_its_peak_and_slips_above(name):
    """The default friction is [2-45] as fitted: no static holding, so under a torque below the
    map's peak the joint creeps at the speed where the map balances the net torque (no chatter
    from the stiff tanh: the velocity keeps its sign), and above the peak it slips away."""
    p = IDENTIFIED[name]
    peak = float(np.max(stribeck(p, np.linspace(0.0, 5.0 * p.vs, 5001))))
    assert 0.4 * p.Fs < peak < 0.8 * p.Fs  # the smooth sign's peak is well under Fs
    for fraction, moves in ((0.5, False), (2.0, True)):
        joint = joint_at_rest(p, friction=True)
        torque = fraction * peak
        dv = torque / p.torque_per_volt
        start = joint.th
        velocities = []
        for _ in range(1500):
            joint.step(pset(V_INI + dv), pset(V_INI))
            velocities.append(joint.w)
        y = joint.th - start
        if moves:
            assert y > 1.0, f"{name}: {fraction} of the peak should slip away"
            continue
        assert 0.0 < y < 1.0 and min(velocities[500:]) > 0.0  # creeping, one way
        net = torque - p.K * y - p.D * joint.w  # what friction must balance [N m]
        assert float(stribeck(p, joint.w)) == pytest.approx(net, rel=0.02)


def test_end_stops_hold_the_joint():
    p = IDENTIFIED["bottom"]
    bias = (pset(V_INI), pset(V_INI))
    joint = JointModel(p, H, 0.0, (-5.0, 5.0), 0.0, bias, friction=False)
    for _ in range(3000):
        joint.step(pset(10.0), pset(0.0))
    assert joint.th == 5.0 and joint.w == 0.0


def test_full_stack_matches_the_model_within_converter_resolution():
    """Through the sim transport's DAC/ADC and the drivers, the step is still [2-50]."""
    sim = make_rig(replace={"friction = true": "friction = false", "adc_noise_volts = 0.0005": "adc_noise_volts = 0.0"})
    p = IDENTIFIED["bottom"]
    q0 = sim.io.read().angles[0]
    angles = []
    for _ in range(3000):
        sim.io.write_pressures(*sim.actuation.outputs([1.0, 0.0]))
        sim.clock.sleep_until(sim.clock.now() + H)
        angles.append(math.degrees(sim.io.read().angles[0] - q0))
    t = np.arange(1, 3001) * H
    expected = analytic_step(*transfer_function(p), t - p.T_dly)
    lsb_deg = 10.0 / 65535 / 5.0 * 333.3
    assert np.max(np.abs(np.array(angles) - expected)) < 3 * lsb_deg + 0.01
