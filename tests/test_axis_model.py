"""The linear pneumatic servo axis (rig-facts §5: hal.linear_axis, hal.linear_axis_facts,
hal.axis_model): the orifice flow law, the parameters' table, what the physics must keep
(pressures between atmosphere and supply, a closed chamber's p V^n, the valve's null holding the
piston), the fixed-step integration against scipy's solve_ivp on the continuous model, the
linearisation against the nonlinear model's small-signal response, the steady motion against
the simulation, and a closed-loop sanity check."""
import dataclasses
import math
import random

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import solve_ivp

from hal.errors import ConfigError
from hal.linear_axis import (
    C1,
    C2,
    P_CR,
    R_AIR,
    R_LAMINAR,
    RHO_ANR,
    AxisParams,
    AxisState,
    chamber_inflow,
    edge_area,
    flow_into,
    friction_magnitude,
    mass_flow,
    spool_of,
)
from hal.linear_axis_facts import balance_pressure, facts, linearise, null_spool, null_volts, rest_state, steady_motion
from hal.axis_model import AxisModel
from tests import doc_blocks

H = 1e-3
FRICTIONLESS = AxisParams(coulomb_n=0.0, static_n=0.0)


def run(model: AxisModel, command, steps: int) -> np.ndarray:
    """Rows (x, v, p_head, p_rod) after each of ``steps`` steps; ``command(k)`` gives step k's volts."""
    out = []
    for k in range(steps):
        model.step(command(k))
        out.append((model.position_m, model.velocity_m_s, model.p_head_pa, model.p_rod_pa))
    return np.array(out)


# --- the orifice ---------------------------------------------------------------------------------

def test_the_flow_constants_are_richer_and_hurmuzlus():
    assert C1 == pytest.approx(0.040418, rel=2e-5)  # [s sqrt(K)/m], k = 1.4, R = 287 J/(kg K): as printed
    assert C2 == pytest.approx(0.156174, rel=2e-5)
    assert P_CR == pytest.approx(0.5283, abs=1e-4)


def test_the_flow_is_continuous_and_smooth_at_the_critical_ratio_and_continuous_at_the_laminar_edge():
    g, up = 1e-5 / math.sqrt(293.15), 7e5
    below, above = flow_into(g, up, up * P_CR * (1 - 1e-9))[0], flow_into(g, up, up * P_CR * (1 + 1e-9))[0]
    assert above == pytest.approx(below, rel=1e-7)
    eps = up * 1e-6  # the slope in the downstream pressure on either side: 0 (choked), and ~0 at the edge
    slope_sub = (flow_into(g, up, up * P_CR + 2 * eps)[0] - flow_into(g, up, up * P_CR + eps)[0]) / eps
    assert abs(slope_sub) * up / below < 1e-3
    edge = up * R_LAMINAR
    assert flow_into(g, up, edge * (1 + 1e-12))[0] == pytest.approx(flow_into(g, up, edge * (1 - 1e-12))[0], rel=1e-7)
    assert flow_into(g, up, up)[0] == 0.0


@pytest.mark.parametrize("p_port, p", [(7e5, 1e5), (7e5, 5e5), (7e5, 6.99e5), (1e5, 6e5), (5e5, 6e5), (6e5, 6.01e5)])
def test_the_flow_runs_both_ways_and_its_derivative_is_exact(p_port, p):
    """Choked, subsonic and laminar, in and out: the implicit step relies on dm/dp."""
    g = 1e-5 / math.sqrt(293.15)
    m, d = flow_into(g, p_port, p)
    assert m == pytest.approx(-flow_into(g, p, p_port)[0], rel=1e-12)
    assert (m > 0) == (p_port > p)
    eps = 1e-3
    assert d == pytest.approx((flow_into(g, p_port, p + eps)[0] - flow_into(g, p_port, p - eps)[0]) / (2 * eps),
                              rel=1e-5)


def test_the_valves_area_gives_back_its_nominal_flow_and_its_null_leaks_the_fraction_asked():
    p = AxisParams()
    p_in = 0.6e6 + p.atmosphere_pa
    q = mass_flow(p.orifice_area_m2, p_in, p_in - 0.1e6, p.temperature_k) / RHO_ANR * 60e3  # [l/min ANR]
    assert q == pytest.approx(700.0, rel=1e-9)
    assert 8e-6 < p.orifice_area_m2 < 16e-6  # an effective diameter of 3-4.5 mm, as the MPYE-1/8's ports
    assert edge_area(p, 0.0) == pytest.approx(0.01 * p.orifice_area_m2, rel=1e-9)
    assert edge_area(p, 1.0) == pytest.approx(p.orifice_area_m2, rel=1e-12)
    assert edge_area(p, -1.0) < 0.02 * edge_area(p, 0.0)  # a covered port leaks less as the land covers it
    assert spool_of(7.5) == 0.5 and spool_of(12.0) == 1.0 and spool_of(-3.0) == -1.0


def test_the_table_builds_the_params_and_refuses_unknown_keys_by_name():
    p = AxisParams.from_table({"bore_m": 0.032, "rod_m": 0.012, "stroke_m": 0.3, "supply_gauge_pa": 5e5})
    assert p.area_head == pytest.approx(math.pi * 0.032 ** 2 / 4)
    assert p.area_rod == pytest.approx(math.pi * (0.032 ** 2 - 0.012 ** 2) / 4)
    assert p.supply_pa == pytest.approx(5e5 + 101_325.0)
    with pytest.raises(ConfigError, match=r"axis\.bore_mm: unknown key \(allowed here: .*bore_m"):
        AxisParams.from_table({"bore_mm": 25}, "axis")
    with pytest.raises(ConfigError, match=r"static_n: must be >= coulomb_n"):
        AxisParams.from_table({"coulomb_n": 30.0, "static_n": 20.0})
    with pytest.raises(ConfigError, match=r"polytropic: must be within 1.0"):
        AxisParams.from_table({"polytropic": 1.67})
    with pytest.raises(ConfigError, match=r"rod_m: must be >= 0 and below the bore"):
        AxisParams.from_table({"rod_m": 0.03})
    with pytest.raises(ConfigError, match=r"stroke_m: expected a number"):
        AxisParams.from_table({"stroke_m": "200 mm"})


# --- what the physics keeps ----------------------------------------------------------------------

@pytest.mark.parametrize("n", [1.0, 1.2, 1.4])
def test_a_closed_chamber_keeps_its_mass_p_v_to_the_n_stays_constant(n):
    """Valve at its null with a leak of a millionth: a force drives the piston, each chamber is
    compressed or expanded with its mass inside (R&H's chamber equation, the volume term)."""
    p = dataclasses.replace(FRICTIONLESS, polytropic=n, null_leak_fraction=1e-6)
    model = AxisModel(p)
    start = model.state()
    model.external_force_n = 60.0
    run(model, lambda k: 5.0 * (1 + start.spool), 300)
    assert model.position_m - start.position_m > 0.005  # it moved: the rod side was compressed
    for head, p0, p1 in ((True, start.p_head_pa, model.p_head_pa), (False, start.p_rod_pa, model.p_rod_pa)):
        v0 = p.volumes(start.position_m)[0 if head else 1]
        v1 = p.volumes(model.position_m)[0 if head else 1]
        assert p1 * v1 ** n == pytest.approx(p0 * v0 ** n, rel=2e-3)


def test_pressures_stay_between_atmosphere_and_supply_unless_the_moving_piston_compresses_a_chamber():
    p = AxisParams()
    for volts in np.linspace(0.0, 10.0, 11):  # a held command from rest, through to the stop: within bounds
        rows = run(AxisModel(p), lambda k: volts, 600)
        assert rows[:, 2:].max() <= p.supply_pa and rows[:, 2:].min() >= p.atmosphere_pa * (1 - 1e-9)
    for seed, load in ((0, 1.0), (2, 5.0)):  # reversals at speed: braking compresses a chamber past the supply
        rng = random.Random(seed)
        commands = [rng.choice([0.0, 10.0, rng.uniform(0.0, 10.0)]) for _ in range(100)]
        rows = run(AxisModel(dataclasses.replace(p, load_mass_kg=load)), lambda k: commands[k // 40], 4000)
        x = rows[:, 0]
        assert rows[:, 2:].min() > p.atmosphere_pa - 20e3
        assert rows[:, 2:].max() > p.supply_pa  # it happens: the test below is not empty
        for k in range(len(rows)):
            recent = x[max(0, k - 50):k + 1]
            if rows[k, 2] > p.supply_pa:
                assert x[k] < recent.max(), f"step {k}: head above supply while nothing compressed it"
            if rows[k, 3] > p.supply_pa:
                assert x[k] > recent.min(), f"step {k}: rod side above supply while nothing compressed it"


def test_the_valves_null_holds_the_axis_and_its_centre_lets_it_drift_slowly_outwards():
    p = AxisParams()
    model = AxisModel(p)
    rest = model.state()
    u_null = null_volts(p)
    assert 4.9 < u_null < 5.0  # the differential cylinder's null sits below the 5 V centre
    run(model, lambda k: u_null, 2000)
    assert model.position_m == rest.position_m and model.velocity_m_s == 0.0
    assert model.p_head_pa == pytest.approx(rest.p_head_pa, rel=1e-9)
    model = AxisModel(p)
    rows = run(model, lambda k: 5.0, 2000)
    top = facts(p).max_speed_extend_m_s
    drift = model.position_m - rest.position_m
    assert 0.0 < drift < 0.01  # outwards (the head's larger area), by stick-slip: a few mm/s
    assert drift / 2.0 < 0.002 * top and np.abs(rows[:, 1]).max() < 0.03 * top


def test_volts_above_the_centre_extend_and_below_it_retract_faster_the_further():
    p = AxisParams()
    moved = {}
    for volts in (3.0, 4.0, 6.0, 7.0):
        model = AxisModel(p)
        run(model, lambda k: volts, 60)
        moved[volts] = model.position_m - 0.1
    assert moved[7.0] > moved[6.0] > 0.0 > moved[4.0] > moved[3.0]


def test_the_end_stops_hold_against_a_fully_open_valve():
    p = AxisParams()
    model = AxisModel(p)
    rows = run(model, lambda k: 10.0, 600)
    assert rows[:, 0].max() == p.stroke_m and model.position_m == p.stroke_m and model.velocity_m_s == 0.0
    assert model.p_head_pa == pytest.approx(balance_pressure(p, 1.0, True), rel=1e-3)
    assert model.p_head_pa > 0.99 * p.supply_pa and model.p_rod_pa < 1.01 * p.atmosphere_pa
    rows = run(model, lambda k: 0.0, 600)
    assert rows[:, 0].min() == 0.0 and model.position_m == 0.0 and model.velocity_m_s == 0.0


def test_bad_input_is_refused_with_its_name():
    model = AxisModel(AxisParams())
    before = model.state()
    with pytest.raises(ValueError, match="valve command nan V"):
        model.step(math.nan)
    assert model.state() == before
    with pytest.raises(ValueError, match="dt 0.0 s"):
        AxisModel(AxisParams(), 0.0)
    with pytest.raises(ValueError, match="outside the stroke"):
        model.rest_state(0.3)
    with pytest.raises(ValueError, match="load_force_n 400.0 N: beyond what the axis can hold"):
        null_spool(AxisParams(load_force_n=400.0))


# --- the integration against the continuous model -------------------------------------------------

def continuous(p: AxisParams, command, steps: int, start: AxisState) -> np.ndarray:
    """The continuous model through solve_ivp (LSODA, tight tolerances), one 1 ms step at a time
    with that step's command held (no discontinuity inside an interval); stiction as a hybrid: at rest while
    |F| <= Fs (a breakaway event), slipping with the Stribeck map until the velocity returns to
    zero (a stop event); without friction one smooth phase. Rows as :func:`run`."""
    rt = R_AIR * p.temperature_k
    target = 0.0

    def parts(y):
        x, v, p1, p2, s = y
        vh, vr = p.volumes(x)
        dp1 = p.polytropic / vh * (rt * chamber_inflow(p, s, p1, True)[0] - p1 * p.area_head * v)
        dp2 = p.polytropic / vr * (rt * chamber_inflow(p, s, p2, False)[0] + p2 * p.area_rod * v)
        force = p.area_head * p1 - p.area_rod * p2 - p.atmosphere_pa * p.area_rod_section + p.load_force_n
        return dp1, dp2, (target - s) / p.valve_time_constant_s, force

    def stuck(t, y):
        dp1, dp2, ds, _ = parts(y)
        return [0.0, 0.0, dp1, dp2, ds]

    def slipping(t, y):
        dp1, dp2, ds, force = parts(y)
        v = y[1]
        force -= p.viscous_n_s_m * v + math.copysign(friction_magnitude(p, abs(v)), v)
        return [v, force / p.moving_mass_kg, dp1, dp2, ds]

    def breakaway(t, y):
        return abs(parts(y)[3]) - p.static_n
    breakaway.terminal, breakaway.direction = True, 1.0

    def stops(t, y):
        return y[1]
    stops.terminal = True

    y, rows = [start.position_m, start.velocity_m_s, start.p_head_pa, start.p_rod_pa, start.spool], []
    for k in range(steps):
        target = spool_of(command(k))
        t0, t1 = k * H, (k + 1) * H
        for _ in range(10):  # phases within the step: a breakaway or a stop at most, in practice
            if t0 >= t1 - 1e-15:
                break
            at_rest = y[1] == 0.0 and abs(parts(y)[3]) <= p.static_n
            if y[1] == 0.0 and not at_rest:  # breaking away now, in the force's direction
                y[1] = math.copysign(1e-12, parts(y)[3])
            events = None if p.static_n == 0.0 else breakaway if at_rest else stops
            sol = solve_ivp(stuck if at_rest else slipping, (t0, t1), y, method="LSODA", rtol=1e-10,
                            atol=[1e-11, 1e-9, 1e-4, 1e-4, 1e-11], events=events)
            assert sol.success, sol.message
            t0, y = sol.t[-1], list(sol.y[:, -1])
            if sol.status == 1 and not at_rest:  # the stop event: at rest, stuck if the force allows
                y[1] = 0.0
        assert t0 >= t1 - 1e-15, f"the reference did not get through step {k}"
        rows.append(y[:4])
    return np.array(rows)


def test_a_valve_step_with_stiction_and_stribeck_friction_matches_solve_ivp():
    p = AxisParams()
    start = rest_state(p, 0.02)
    model = AxisModel(p, H, start)
    rows = run(model, lambda k: 6.0, 150)
    reference = continuous(p, lambda k: 6.0, 150, start)
    assert rows[-1, 0] - start.position_m > 0.1  # a long move, through breakaway and the spring's ringing
    error = np.abs(rows - reference).max(axis=0)
    assert error[0] < 1e-3 and error[1] < 0.02 and error[2] < 4e3 and error[3] < 4e3, error


def test_a_sine_about_the_null_without_friction_matches_solve_ivp():
    p = FRICTIONLESS
    start = rest_state(p, 0.1)

    def command(k):
        return null_volts(p) + 0.3 * math.sin(2 * math.pi * 3.0 * k * H)
    rows = run(AxisModel(p, H, start), command, 500)
    reference = continuous(p, command, 500, start)
    assert np.ptp(rows[:, 0]) > 0.03  # the piston swings through 30 mm and back, the velocity reversing
    error = np.abs(rows - reference).max(axis=0)
    assert error[0] < 3e-4 and error[1] < 4e-3 and error[2] < 1e3 and error[3] < 1e3, error


# --- what a controller is told -----------------------------------------------------------------

@pytest.mark.parametrize("position_m", [0.1, 0.04, 0.16])
def test_the_linearised_model_matches_the_small_signal_response(position_m):
    """A 2 mm/s kick from rest at the null, and a 5 mV valve step from it, without Coulomb
    friction (the linearisation leaves it out)."""
    p = FRICTIONLESS
    lin = linearise(p, position_m)
    model = AxisModel(p, H, dataclasses.replace(lin.rest, velocity_m_s=0.002))
    rows = run(model, lambda k: lin.null_volts, 400)
    x = rows[:, 0] - position_m
    t = np.arange(0, 401) * H
    _, y, _ = signal.lsim(signal.StateSpace(lin.a, lin.b, lin.c, np.zeros((1, 1))), np.zeros(401), t,
                          X0=[0.0, 0.002, 0.0, 0.0])
    assert np.abs(x - y[1:]).max() < 0.05 * np.abs(x).max()
    poles = np.linalg.eigvals(lin.a)
    ringing = poles[np.argmax(poles.imag)]
    # the nonlinear model's own ringing: the period between the velocity's zero crossings
    v = rows[:, 1]
    crossings = [k + v[k] / (v[k] - v[k + 1]) for k in range(len(v) - 1) if v[k] * v[k + 1] < 0.0]
    period = (crossings[2] - crossings[0]) * H  # two half-periods
    assert 2 * math.pi / period == pytest.approx(ringing.imag, rel=0.03)
    assert lin.natural_frequency_rad_s == pytest.approx(abs(ringing), rel=0.02)  # the third-order form's wn
    # a small valve step from the null: the input matrix and the velocity gain K_v
    model = AxisModel(p, H, lin.rest)
    x = run(model, lambda k: lin.null_volts + 0.005, 500)[:, 0] - position_m
    _, y, _ = signal.lsim(signal.StateSpace(lin.a, lin.b, lin.c, np.zeros((1, 1))), np.full(501, 0.005),
                          np.arange(0, 501) * H)
    assert np.abs(x - y[1:]).max() < 0.02 * np.abs(x).max()
    assert (x[-1] - x[-11]) / (10 * H) == pytest.approx(lin.velocity_gain_m_s_v * 0.005, rel=0.03)
    num, den = lin.transfer_function()
    assert np.roots(den)[np.argmax(np.roots(den).imag)] == pytest.approx(
        complex(-lin.damping_ratio * lin.natural_frequency_rad_s,
                lin.natural_frequency_rad_s * math.sqrt(1 - lin.damping_ratio ** 2)), rel=1e-9)


@pytest.mark.parametrize("volts", [10.0, 0.0, 6.5, 3.5])
@pytest.mark.parametrize("load_n", [0.0, 80.0, -80.0])
def test_the_steady_motion_is_a_motion_the_simulation_keeps_and_the_top_speed_is_not_passed(volts, load_n):
    p = AxisParams(stroke_m=1.0, load_force_n=load_n)
    speed, p_head, p_rod = steady_motion(p, volts)
    assert speed * (volts - 5.0) > 0.0
    model = AxisModel(p, H, AxisState(0.1 if speed > 0 else 0.9, speed, p_head, p_rod, spool_of(volts)))
    rows = run(model, lambda k: volts, 100)
    assert np.abs(rows[:, 1] - speed).max() < 1e-6 * abs(speed)
    model = AxisModel(p, H, rest_state(p, 0.02 if speed > 0 else 0.98))  # from rest: the top speed bounds it
    rows = run(model, lambda k: volts, 600)
    assert np.abs(rows[:, 1]).max() < 1.02 * abs(speed)  # but for the spring's ringing


def test_the_facts_at_mid_stroke():
    f = facts(AxisParams())
    assert f.null_volts == pytest.approx(null_volts(AxisParams()))
    assert 2 * math.pi * f.natural_frequency_hz == pytest.approx(math.sqrt(f.stiffness_n_m / 1.2), rel=1e-12)
    assert f.max_speed_extend_m_s > f.max_speed_retract_m_s > 1.0  # the head's larger area
    area_head = math.pi * 0.025 ** 2 / 4
    assert f.stall_force_extend_n == pytest.approx(area_head * 0.6e6, rel=0.01)  # A_h (p_s - p_atm)
    assert f.stall_force_extend_n > f.stall_force_retract_n > 0.0


@pytest.mark.parametrize("start_m, move_m", [(0.1, 0.05), (0.1, -0.05), (0.03, 0.05), (0.17, -0.05)])
def test_a_pd_position_loop_settles_a_50_mm_step_within_1_mm_in_under_2_s(start_m, move_m):
    """A physics sanity check, not the product's controller: u = V_null + Kp e - Kd v, Kp = 40 V/m,
    Kd = 3 V s/m (v by the difference of the measured positions), saturated to 0-10 V. A P loop
    alone hunts here (stick-slip, about +-1.5 mm): the velocity term damps the slip that follows
    each breakaway."""
    p = AxisParams()
    model = AxisModel(p, H, rest_state(p, start_m))
    target, u_null, kp, kd = start_m + move_m, null_volts(p), 40.0, 3.0
    errors, last = [], model.position_m
    for _ in range(3000):
        x = model.position_m
        model.step(min(max(u_null + kp * (target - x) - kd * (x - last) / H, 0.0), 10.0))
        last = x
        errors.append(abs(target - model.position_m))
    assert max(errors[2000:]) < 1e-3  # within 1 mm from 2 s on (it settles in about 0.4 s)
    assert min(errors[:2000]) < 1e-3


def test_the_documented_snippet_runs():
    code = doc_blocks.snippet("docs/simulator.md", "The linear axis", match=r"from hal\.linear_axis").text
    namespace: dict = {}
    exec(compile(code, "docs/simulator.md", "exec"), namespace)
    assert abs(namespace["model"].position_m - 0.1) > 0.001
