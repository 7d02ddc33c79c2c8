"""What a planner hands the loop, and what it knows of the rig: shared by the motion
planners (:mod:`daemon.planner.commands`) and the excitation planner
(:mod:`daemon.planner.excitation`), which both build on them. Positions in SI inside (rad on
a rotary joint, m on a linear one), at the protocol in the joint's display unit (deg, mm);
durations in s."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from controllers import trajectory
from controllers.feasibility import Authority, Infeasible
from controllers.feasibility_axis import AxisAuthority
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed, bad_args, number_text
from hal.interfaces import DISPLAY


@dataclass(frozen=True)
class PlanContext:
    """What the planner knows of the rig: built once in the daemon, sent with each job (small)."""

    joint_names: tuple[str, ...]
    limits: tuple[tuple[float, float], ...]  # [rad; m on a linear joint]
    link_lengths_m: tuple[float, ...]
    elbow: int
    authority: Authority | None  # None when a joint has no identified model: no authority check
    muscles: tuple = ()  # hal.muscle.MuscleJoint per joint (None: a cylinder joint, it takes no stiffness)
    units: tuple[str, ...] = ()  # each joint's position unit, "rad" or "m" (default: all rad)
    margins: tuple[float, ...] = ()  # how far inside its limits a set-point must be [rad; m] (default: none)

    @classmethod
    def of(cls, rig, context) -> "PlanContext":
        fraction = rig.limits.authority_fraction
        if all(m is not None for m in context.models):
            authority = Authority.of(rig, context, fraction)
        elif context.axes and all(a is not None for a in context.axes):
            authority = AxisAuthority.of(context, fraction)
        else:
            authority = None
        return cls(tuple(context.joint_names), tuple(j.limits for j in rig.joints), tuple(rig.arm.link_lengths_m),
                   rig.arm.elbow, authority, tuple(context.muscles), tuple(j.position_unit for j in rig.joints),
                   rig.setpoint_margins)

    @property
    def n(self) -> int:
        return len(self.joint_names)

    def unit(self, j: int) -> str:
        return self.units[j] if self.units else "rad"

    def display(self, j: int) -> tuple[str, float]:
        """Joint j's display unit and its scale from SI: ("deg", 180/pi) or ("mm", 1000)."""
        return DISPLAY[self.unit(j)]

    def to_si(self, values: Sequence[float]) -> list[float]:
        """One position per joint in its display unit (deg, mm) -> SI (rad, m)."""
        return [v / self.display(j)[1] for j, v in enumerate(values)]

    def shown(self, values: Sequence[float]) -> list[float]:
        """SI positions -> each joint's display unit."""
        return [v * self.display(j)[1] for j, v in enumerate(values)]

    def text(self, j: int, value: float, digits: int = 2) -> str:
        unit, scale = self.display(j)
        return f"{number_text(value * scale, digits)} {unit}"

    def margin_words(self, j: int, margin: float, kept: str) -> tuple[str, float]:
        """What a refusal within joint j's set-point ``margin`` [SI] of its limits says after "within"
        ("3 deg of its limits 85.0..175.0 deg: set-points keep 3 deg inside (...), so 88.0..172.0 deg"),
        ``kept`` naming what keeps it, and the margin in the joint's unit (the rig file's figure,
        not its round trip through SI)."""
        lo, hi = self.limits[j]
        unit, scale = self.display(j)
        shown = round(margin * scale, 6)
        return (f"{shown:g} {unit} of its limits {lo * scale:.1f}..{hi * scale:.1f} {unit}: {kept} keep {shown:g} "
                f"{unit} inside (the rig file's [safety] setpoint_margin_{unit}), so {(lo + margin) * scale:.1f}.."
                f"{(hi - margin) * scale:.1f} {unit}"), shown

    def require_rotary(self, argument: str) -> None:
        """bad_args naming ``argument`` (an angle or a tip point) on a rig with a linear joint."""
        linear = [name for j, name in enumerate(self.joint_names) if self.unit(j) != "rad"]
        if linear:
            raise bad_args(f"{argument}: joint {linear[0]} is linear: give its position in mm with positions "
                           f"(one per joint, deg on a rotary joint, mm on a linear one)", argument)


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
