"""``python -m tests.forbid_planning [pneumad options]``: the real daemon, with the planning
code made to fail in the daemon's own process. Its worker processes are spawned fresh and
keep the real code, so a daemon run this way works exactly when every limit and authority
check, reference profile, design parse and parameter derivation runs beside the loop, and
the array sensor's contact estimator in its own process: a structural proof, used by
tests/test_every_command.py and tests/test_contact_daemon.py, with no timing in it."""
import sys

from controllers import (  # noqa: F401 (signals: subclasses)
    contact_force,
    feasibility,
    lti_design,
    profile,
    registry,
    signals,
    trajectory,
)
from daemon.planner import excitation as excite_plan, commands as planner
from daemon import main
from hal import kinematics


def forbidden(*args, **kwargs):
    raise AssertionError("planning ran in the loop's process")


def _subclasses(cls):
    for sub in cls.__subclasses__():
        yield sub
        yield from _subclasses(sub)


def forbid() -> None:
    for cls in (trajectory.Trajectory, *_subclasses(trajectory.Trajectory)):
        if "profile" in vars(cls):
            setattr(cls, "profile", forbidden)
    for cls in _subclasses(signals.Excitation):
        if "series" in vars(cls):  # a signal's whole run: planning and analysis, never a cycle
            setattr(cls, "series", forbidden)
    excite_plan.signal_of = excite_plan.predicted_excursion = excite_plan.plan_excite = forbidden
    for name in ("check", "shortest", "shortfalls"):
        setattr(feasibility.Authority, name, forbidden)
    profile.first_outside_limits = planner.first_outside_limits = forbidden
    profile.tip_profile = trajectory.tip_profile = forbidden
    kinematics.inverse_2link_array = forbidden
    lti_design.parse = forbidden
    registry.prepare_change = forbidden
    contact_force.ContactEstimator.update = forbidden  # a frame's estimate: the sensor's process alone


if __name__ == "__main__":
    forbid()
    sys.exit(main.main(sys.argv[1:]))
