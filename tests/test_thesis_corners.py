"""Issue 32: every built-in controller holds a set-point on the thesis's uncertainty corners
(bench/thesis_corners.py runs the whole grid); here the corners that tripped SMC+DOB before its
middle joint's Q filter was designed for them, and the thesis's own corner."""
import math

import pytest

from bench import scenarios as S
from bench.robustness import CONTROLLERS, Plant, paths
from bench.thesis_corners import THESIS_CORNER

HARSHEST = (
    Plant("gain 1.41/1.41, friction x1.5, damping x0.5, delay x1.5", (1.41, 1.41), 1.5, 1.5, damping=0.5),
    Plant("gain 0.41/1.41, friction x0.5, damping x0.5, delay x1.5", (0.41, 1.41), 0.5, 1.5, damping=0.5),
    THESIS_CORNER,
)


@pytest.mark.slow(seconds=8)  # each controller: three 8 s holds, about 6 s on the 2-core VM
@pytest.mark.parametrize("controller", CONTROLLERS)
def test_no_controller_trips_while_holding_on_the_thesis_corners(controller):
    for plant in HARSHEST:
        loop = S.make_loop(controller, options=S.example_options(controller), plant=plant.sim_options())
        loop.hold()
        for _ in range(80):  # 8 s, the daemon's supervisor and tracking rule on
            loop.run(100)
            if loop.state.value != "enabled":
                break
        assert loop.state.value == "enabled", (plant.name, loop.supervisor.cause)


@pytest.mark.slow(seconds=3)  # a few seconds: kept out of the fast subset
@pytest.mark.parametrize("controller", ["smc", "smc_dob"])
def test_sliding_mode_holds_after_a_fast_path_without_alternating_its_output_every_cycle(controller):
    """The vertical line at the fastest the rig's authority allows (1.5 s), nominal plant without
    noise, then a hold: with the middle joint's boundary layer sized for the bottom joint (a volt
    moves the middle joint's sigma 7.5 times as much), its output alternated every cycle while
    holding (0.4-0.8 V peak to peak, 340-400 V/s of output motion). Now it moves under 5 V/s."""
    loop = S.make_loop(controller, options=S.example_options(controller))
    path = paths(loop, with_circle=False)["line"]
    loop = S.make_loop(controller, plant=Plant("nominal, no noise", noise=False).sim_options(),
                       replace=S.NO_TRACKING_RULE)
    S.approach(loop, path.sample(0.0)[0])
    loop.set_trajectory(path, "path")
    loop.run(round((path.duration + 3.0) / loop.period))  # the path, then 3 s of holding
    last, motion = list(loop.u), [0.0] * loop.n
    for _ in range(2000):  # 2 s more of holding, watched
        loop.run(1)
        assert loop.state.value == "enabled", loop.supervisor.cause
        motion = [m + abs(u - v) for m, u, v in zip(motion, loop.u, last)]
        last = list(loop.u)
    assert max(motion) / 2.0 < 5.0, [round(m / 2.0, 1) for m in motion]  # [V/s], each joint
    assert all(abs(math.degrees(r - a)) < 1.0 for r, a in zip(loop.reference[0], loop.angles))
