"""The LTI state-space controller from a design file: the file formats, the c2d helper, the
checks on a design, and the controller on the simulated rig through the real loop."""
import copy
import math

import numpy as np
import pytest

from bench import scenarios as S
from controllers import lti_design, registry
from controllers.base import ParamError
from controllers.trajectory import JointMove

PI_FILE = lti_design.EXAMPLE
PI = lti_design.read_file(PI_FILE)
NAMES = ("bottom", "middle")


def lag_lead(k: float, a: float, b: float, **extra) -> dict:
    """k (s + a) / (s + b) as x' = -b x + e, u = k (a - b) x + k e; e in deg."""
    joint = {"input": "error_deg", "dt": 0.0, "A": [[-b]], "B": [[1.0]], "C": [[k * (a - b)]], "D": [[k]], **extra}
    return {"joints": {"bottom": joint, "middle": dict(joint)}}


@pytest.mark.slow  # long: kept out of the fast subset
def test_the_thesis_pi_written_as_matrices_tracks_as_the_built_in_pid_does():
    results = {}
    for name, options in (("pid", None), ("lti", {"design": PI})):
        loop = S.make_loop("pid")
        loop.switch(registry.build(name, loop.context, options=options))
        results[name] = S.run_path(loop, S.make_path(loop, "translation", 15.0))
    for a, b in zip(results["pid"].joint_max, results["lti"].joint_max):
        assert a == pytest.approx(b, abs=0.05)  # Tustin against forward Euler: the same controller
    assert results["lti"].tip_max == pytest.approx(results["pid"].tip_max, abs=0.1)


@pytest.mark.parametrize("method, pole", [("bilinear", (1 - 2.5e-3) / (1 + 2.5e-3)), ("zoh", math.exp(-5e-3))])
def test_a_continuous_design_is_discretised_at_the_loop_period_keeping_its_static_gain(method, pole):
    k, a, b = 0.5, 1.0, 5.0  # static gain k a / b = 0.1 V/deg
    bottom, _ = lti_design.parse(lag_lead(k, a, b, method=method), NAMES, 0.001)
    assert bottom.poles()[0] == pytest.approx(pole, rel=1e-9)
    assert bottom.static_gain() == pytest.approx(k * a / b * 180 / math.pi, rel=1e-6)  # V/rad
    pi_bottom, _ = lti_design.parse(PI, NAMES, 0.001)
    assert math.isinf(pi_bottom.static_gain())  # the integrator survives discretisation


def test_a_design_saved_as_npz_by_the_helper_loads_to_the_same_controller(tmp_path, capsys):
    out = tmp_path / "pi.npz"
    assert lti_design.main([str(PI_FILE), "--dt", "0.001", "--out", str(out)]) == 0
    assert "static gain integrating" in capsys.readouterr().out
    for toml, npz in zip(lti_design.parse(PI, NAMES, 0.001), lti_design.parse(lti_design.read_file(out), NAMES, 0.001)):
        np.testing.assert_allclose(npz.a, toml.a)
        np.testing.assert_allclose(npz.b, toml.b)
        np.testing.assert_allclose(npz.c, toml.c)
        assert npz.d == pytest.approx(toml.d)
    with pytest.raises(ParamError, match="made for dt = 0.001 s but the loop runs at 0.002 s"):
        lti_design.parse(lti_design.read_file(out), NAMES, 0.002)


def _broken(path, value):
    design = copy.deepcopy(PI)
    target = design
    for key in path[:-1]:
        target = target[key]
    if value is None:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return design


@pytest.mark.parametrize("design, message", [
    (_broken(("joints", "bottom", "A"), [[0.0, 1.0]]), r"A n x n, B n x 1.*got A 1x2"),
    (_broken(("joints", "bottom", "C"), [[math.nan]]), "C must hold finite numbers"),
    (_broken(("joints", "bottom", "D"), "0.8"), "D must be a list of rows"),
    (_broken(("joints", "middle"), None), r"no controller for joint\(s\) middle"),
    (_broken(("joints", "elbow"), PI["joints"]["bottom"]), "joint 'elbow', which this rig does not have"),
    (_broken(("joints", "bottom", "method"), "magic"), "method must be one of"),
    (_broken(("joints", "bottom", "input"), "error_furlongs"), "input must be one of"),
    (_broken(("joints", "bottom", "gain"), 2.0), "unknown field 'gain'"),
    (_broken(("joints", "bottom", "dt"), -1.0), "dt must be 0"),
    (_broken(("joints", "bottom", "A"), [[0.0] * 40] * 40), r"order 40 exceeds 32"),
    ([1, 2, 3], "must be a map with a 'joints' map"),
])
def test_a_design_that_will_not_do_is_refused_with_what_is_wrong(design, message):
    ctx = S.make_loop("pid").context
    with pytest.raises(ParamError, match=message):
        registry.build("lti", ctx, options={"design": design})


def test_the_lti_controller_requires_its_design_and_knows_no_other_option():
    ctx = S.make_loop("pid").context
    with pytest.raises(ParamError, match="option 'design' is required"):
        registry.build("lti", ctx)
    with pytest.raises(ParamError, match="unknown option 'colour'"):
        registry.build("lti", ctx, options={"design": PI, "colour": "red"})
    with pytest.raises(ParamError, match="unknown option 'design'"):
        registry.build("pid", ctx, options={"design": PI})


@pytest.mark.slow(seconds=3)  # a few seconds: kept out of the fast subset
def test_a_saturating_step_does_not_wind_up_the_design_state():
    """The bottom joint's 10 deg step saturates V_MV: with the state held while clamped the
    PI design overshoots little, as the PID with its anti-windup does (about 6 %)."""
    overshoots = {}
    for name, options in (("pid", None), ("lti", {"design": PI})):
        loop = S.make_loop("pid")
        loop.switch(registry.build(name, loop.context, options=options))
        start = list(loop.reference[0])
        S.approach(loop, start)
        target = list(start)
        target[0] += math.radians(10.0)
        loop.set_trajectory(JointMove(start, target, 0.0), "step")
        peak = -math.inf
        saturated = False
        for _ in range(8000):
            loop.run(1)
            peak = max(peak, loop.angles[0])
            saturated |= loop.u[0] >= loop.context.u_max[0]
        assert saturated
        overshoots[name] = (peak - target[0]) / math.radians(10.0)
    assert overshoots["lti"] < 0.15 and overshoots["lti"] == pytest.approx(overshoots["pid"], abs=0.06)


def test_a_live_gain_change_scales_the_output_next_cycle():
    loops = []
    for _ in range(2):  # the same run twice; then one of them halves the bottom joint's gain
        loop = S.make_loop("pid")
        loop.switch(registry.build("lti", loop.context, options={"design": PI}))
        loop.run(3000)
        target = list(loop.reference[0])
        target[0] += math.radians(1.0)
        loop.set_trajectory(JointMove(loop.reference[0], target, 0.0), "step")
        loop.run(5)
        loops.append(loop)
    changed, twin = loops
    assert changed.u == twin.u
    changed.controller.set_params({"gain": [0.5, 1.0]})
    changed.run(1)
    twin.run(1)
    assert changed.u[0] == pytest.approx(0.5 * twin.u[0], rel=1e-9) and changed.u[1] == twin.u[1]
    with pytest.raises(ParamError, match=r"gain\[bottom\] = 11.0 - is outside 0.0..10.0"):
        changed.controller.set_params({"gain": [11.0, 1.0]})
