"""Issue 32: every built-in controller holds a set-point on the thesis's uncertainty corners
(bench/thesis_corners.py runs the whole grid); here the corners that tripped SMC+DOB before its
middle joint's Q filter was designed for them, and the thesis's own corner."""
import pytest

from bench import scenarios as S
from bench.robustness import CONTROLLERS, Plant
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
