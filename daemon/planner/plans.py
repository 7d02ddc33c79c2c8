"""What a planner hands the loop, and what it knows of the rig: shared by the motion
planners (:mod:`daemon.planner.commands`) and the excitation planner
(:mod:`daemon.planner.excitation`), which both build on them. Angles in rad, durations in s."""
from __future__ import annotations

from dataclasses import dataclass

from controllers import trajectory
from controllers.feasibility import Authority, Infeasible
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed



@dataclass(frozen=True)
class PlanContext:
    """What the planner knows of the rig: built once in the daemon, sent with each job (small)."""

    joint_names: tuple[str, ...]
    limits: tuple[tuple[float, float], ...]  # [rad; m on a linear joint]
    link_lengths_m: tuple[float, ...]
    elbow: int
    authority: Authority | None  # None when a joint has no identified model: no authority check
    muscles: tuple = ()  # hal.muscle.MuscleJoint per joint (None: a cylinder joint, it takes no stiffness)

    @classmethod
    def of(cls, rig, context) -> "PlanContext":
        models_known = all(m is not None for m in context.models)
        return cls(tuple(context.joint_names), tuple(j.limits for j in rig.joints), tuple(rig.arm.link_lengths_m),
                   rig.arm.elbow, Authority.of(rig, context, rig.limits.authority_fraction) if models_known else None,
                   tuple(context.muscles))

    @property
    def n(self) -> int:
        return len(self.joint_names)


@dataclass
class Plan:
    """A checked reference, ready for the loop to install, and what the reply will say."""

    trajectory: trajectory.Trajectory
    name: str  # what status.reference shows while it runs
    reply: dict
    start: tuple[float, ...]  # the set-point it was planned from [rad]
    record: str | None = None  # the name of the daemon's recording of it (``record: true``)
    stiffness: tuple[float, ...] | None = None  # a new stiffness set-point per joint [N m/rad] (``set``)
    generation: int = -1  # the loop's reference generation it was planned against (-1: none); the
    #                       loop installs it only if that is still the one in force (ControlLoop.install)


def check_authority(ctx: PlanContext, what: str, reference: trajectory.Trajectory, fixed: str | None = None,
                    shortest_for: str | None = None) -> None:
    """A refusal with the numbers and the shortest duration that would do (rig-facts §1
    "Authority") unless the rig can deliver ``reference``; see :meth:`Authority.check`.
    ``shortest_for`` names the argument that duration is for (``data.shortest_for``)."""
    if ctx.authority is None:
        return
    try:
        ctx.authority.check(reference, fixed)
    except Infeasible as exc:
        data = exc.data()
        data["shortest_for"] = shortest_for if data["shortest_s"] is not None else None
        raise CommandFailed(P.REFUSED, f"{what} in {reference.duration:g} s is {exc}", data) from None
