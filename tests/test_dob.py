"""The disturbance observer on its own nominal plant: with the model exact, what it estimates
is the input disturbance itself, late by the dead time and the Q filter."""
from collections import deque

import numpy as np
import pytest
from scipy.signal import cont2discrete

from controllers.dob import DisturbanceObserver
from controllers.nominal import NominalJoint
from hal import config

DT = 0.001


def nominal_plant(model):
    """x[k+1] = Ad x[k] + Bd v[k - N] of [2-43] by zero-order hold, v = V_MV + offset + d."""
    a, b = model.state_space()
    ad, bd, *_ = cont2discrete((a, b, np.eye(3), np.zeros((3, 1))), DT, method="zoh")
    return ad, bd.ravel()


@pytest.mark.parametrize("joint", [0, 1])
def test_a_step_input_disturbance_is_estimated_at_its_size_and_nothing_before_it(joint):
    rig = config.load()
    model = NominalJoint.from_rig(rig.joints[joint], rig.joint_params(rig.joints[joint]))
    ad, bd = nominal_plant(model)
    u, d_step = 0.5, 0.3  # V_MV held [V], the disturbance that arrives at 1 s [V]
    v0 = u + model.input_offset
    x = np.linalg.solve(np.eye(3) - ad, bd * v0)  # at rest under u
    observer = DisturbanceObserver((model,), DT, (0.05,), (10.0,))
    observer.reset([x[0]], [u])
    pipe = deque([v0] * model.delay_steps(DT), maxlen=model.delay_steps(DT) + 1)
    estimates = []
    for k in range(4000):
        d = d_step if k >= 1000 else 0.0
        estimates.append(observer.estimate([x[0]])[0])
        observer.sent([u])
        pipe.append(u + model.input_offset + d)
        x = ad @ x + bd * pipe.popleft()
    assert max(abs(e) for e in estimates[:1000]) < 1e-6  # at rest and undisturbed: nothing
    assert estimates[-1] == pytest.approx(d_step, rel=1e-3)  # 3 s on: all of it
    assert abs(estimates[1000 + model.delay_steps(DT)]) < 0.05 * d_step  # it cannot see before the dead time
