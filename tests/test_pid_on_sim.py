"""The thesis PID gains of rig-facts §1 close the loop on both simulated joints."""
import math

import pytest

from controllers.pid import PID
from daemon.testing.simrig import closed_loop, make_rig
from tests.simrig import deg, step_metrics

STEP_AT = 1.0


def step_run(joint, seconds, **rig):
    sim = make_rig(**rig)
    q0 = list(sim.io.read().angles)

    def reference(t):
        q = list(q0)
        if t >= STEP_AT:
            q[joint] += math.radians(10.0)
        return q

    t, angles, outputs = closed_loop(sim, PID(sim.context()), reference, seconds)
    y = [deg(a[joint]) for a in angles]
    other = [deg(a[1 - joint] - q0[1 - joint]) for a in angles]
    return t, y, deg(q0[joint]), other, outputs


def rise_time(t, y, y0, step):
    return next(ti for ti, yi in zip(t, y) if yi - y0 >= 0.9 * step) - STEP_AT


def test_bottom_joint_10_deg_step_settles_within_about_2_s():
    t, y, y0, other, u = step_run(0, 6.0)
    overshoot, settle = step_metrics(t, y, y0, 10.0, STEP_AT)
    assert 0.0 < overshoot < 15.0
    assert settle < 2.2
    assert max(abs(v) for v in other) < 0.5  # the middle joint held its place
    assert max(o[0] for o in u) <= 6.0  # V_MV never exceeds its 0-10 V room (bias 4 V)


@pytest.mark.slow  # long: kept out of the fast subset
def test_middle_joint_settles_under_the_thesis_pid_as_the_bottom_one_does():
    """The reconstructed rig (issue 32) scales the middle joint so the thesis's PID crosses over
    where it does on the bottom joint: its step rises about as fast, and with the identified
    friction (no stiction) it settles and stays (docs/simulator.md)."""
    t, y, y0, other, _ = step_run(1, 20.0)
    tb, yb, yb0, _, _ = step_run(0, 6.0)
    assert 0.5 < rise_time(t, y, y0, 10.0) / rise_time(tb, yb, yb0, 10.0) < 2.0
    overshoot, settle = step_metrics(t, y, y0, 10.0, STEP_AT)
    assert overshoot < 15.0 and settle < 5.0
    late = [yi - y0 for ti, yi in zip(t, y) if ti > STEP_AT + 10.0]
    assert max(abs(v - 10.0) for v in late) < 0.5


def test_middle_joint_without_friction_settles():
    t, y, y0, _, _ = step_run(1, 20.0, replace={"friction = true": "friction = false"})
    overshoot, settle = step_metrics(t, y, y0, 10.0, STEP_AT)
    assert overshoot < 25.0 and settle < 15.0
