"""The planner's side of the commands: everything a request asks for whose cost grows with its
arguments or the rig, beside the loop.

Runs in the preparation worker process (:mod:`daemon.planner.process`), never in the loop's.
Controller commands: decode the arguments, then build and validate a controller (a design's
c2d, a Riccati solve) or derive a parameter change (:func:`build_controller`,
:func:`prepare_change`). Motion commands: decode the arguments (up to a 64 KiB list of
waypoints), check them, build
the reference (inverse kinematics over a path, waypoint and step tables), checks it against
the joint limits, the arm's reach and the rig's authority (:mod:`controllers.feasibility`),
chooses the approach move's duration when the request does not, and hands back a finished
:class:`Plan`. The loop only installs it at a cycle boundary (:mod:`daemon.loop.commands`).

Each planner takes the request's arguments and the set-point in force when the request was
taken [rad], and raises :class:`~daemon.wire.arguments.CommandFailed` with the numbers when it
refuses. Angles in rad inside, deg at the protocol; durations in s.
"""
from __future__ import annotations

import math
import time
from collections.abc import Sequence

from controllers import registry, trajectory
from controllers.base import Controller, ControllerContext, joint_values
from controllers.profile import first_outside_limits
from daemon.planner import excitation
from daemon.planner.plans import Plan, PlanContext, check_authority
from daemon.wire import catalog
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed, bad_args, checked_number, checked_numbers, number, numbers
from hal import kinematics

APPROACH_MARGIN = 1.25  # an approach with no approach_s takes this times its shortest feasible duration
APPROACH_MIN_S = 0.5  # ... and at least this long [s]
PATHS = {"translation": (trajectory.translation, 15.0), "circle": (trajectory.circle, 20.0)}


def _number(cmd: str, args: dict, key: str, default: float | None = None) -> float:
    """A motion argument in the catalog's bounds, or its default (the catalog's, or ``default``)."""
    spec = catalog.COMMANDS[cmd].arg(key)
    return number(args, key, spec.low, spec.high, spec.default if default is None else default)


def build_controller(context: ControllerContext, plugins: dict[str, str], request: dict,
                     set_before: dict[str, dict], active_as: str) -> tuple[Controller, str, dict, dict, dict]:
    """``controller.switch`` / ``controller.shadow``: the named controller, built and validated,
    with the parameters clients set on it before (``set_before[name]``, what the daemon kept)
    under those the request gives: (controller, name, carried, given, reset). ``reset``: the
    parameters set on the active controller (``active_as``) that the new one also has, at
    another value (``{name: {was, now}}``): a switch to another controller starts from its own
    values, and says which of the user's it leaves. The name must be registered (a built-in, an
    entry point, or one of the daemon's configured ``plugins``): a request never names a
    module to import."""
    args = P.decode_args(request)  # checked against the catalog by the messenger
    name, given = args["name"], args.get("params", {})
    carried = {k: v for k, v in set_before.get(name, {}).items() if k not in given}
    controller = registry.build(name, context, {**carried, **given}, args.get("options", {}), plugins=plugins,
                                paths=False)
    now = controller.get_params()
    reset = {}
    if name != active_as:
        for key, was in set_before.get(active_as, {}).items():
            if key in now and now[key] != joint_values(was, context.n):
                reset[key] = {"was": was, "now": now[key]}
    return controller, name, carried, given, reset


def prepare_change(cls: type[Controller], context: ControllerContext, options: dict, values: dict,
                   request: dict):
    """``controller.set``: the running controller's change, derived whole by a twin; and the
    parameters the request set (which a later switch back to it carries)."""
    params = P.decode_args(request)["params"]  # a map of at least one: checked against the catalog by the messenger
    return registry.prepare_change(cls, context, options, values, params), params


def plan(ctx: PlanContext, request: dict, setpoint: Sequence[float], generation: int) -> Plan:
    """The worker's entry point: decode and plan one motion request from ``setpoint``, the
    loop's set-point in reference ``generation``."""
    args = P.decode_args(request)
    record = args.pop("record", False)  # a boolean: checked against the catalog by the messenger
    plan = PLANNERS[request["cmd"]](ctx, args, list(setpoint))
    plan.generation = generation
    if record:
        plan.record = f"{time.strftime('%Y%m%d-%H%M%S')}-{request['cmd']}-{plan.name}"
    return plan


def plan_set(ctx: PlanContext, args: dict, setpoint: list[float]) -> Plan:
    """Move to joint positions (``positions``: deg on a rotary joint, mm on a linear one), joint
    angles (``angles_deg`` or ``angles_rad``) or a tip point (``xy_mm``), in
    ``duration_s`` with cubic time scaling (0: a step); where the joints take one, with a new
    stiffness set-point (``stiffness_nm_deg``, one number or one per joint)."""
    duration = _number("set", args, "duration_s")  # exactly one of the four, numbers: the catalog's (the messenger)
    if "positions" in args:
        target = ctx.to_si(numbers(args, "positions", ctx.n))
    elif "angles_deg" in args:
        ctx.require_rotary("angles_deg")
        target = [math.radians(a) for a in numbers(args, "angles_deg", ctx.n)]
    elif "angles_rad" in args:
        ctx.require_rotary("angles_rad")
        target = numbers(args, "angles_rad", ctx.n)
    else:
        ctx.require_rotary("xy_mm")
        target = tip_angles(ctx, [float(v) for v in args["xy_mm"]]) + setpoint[2:]
    check_limits(ctx, target)
    stiffness = stiffness_setpoint(ctx, args, target) if "stiffness_nm_deg" in args else None
    move = trajectory.JointMove(setpoint, target, duration)
    rotary = all(ctx.unit(j) == "rad" for j in range(ctx.n))
    held = f"the rig cannot hold that {'angle' if rotary else 'position'}"
    check_authority(ctx, "the move", move, None if duration else held, "duration_s")
    reply = {"target": ctx.shown(target), "duration_s": duration}
    if rotary:
        reply["target_deg"] = [math.degrees(q) for q in target]
    if stiffness is not None:
        reply["stiffness_nm_deg"] = [k / DEG_PER_RAD for k in stiffness]
    return Plan(move, "set", reply, tuple(setpoint), stiffness=stiffness)


DEG_PER_RAD = 180.0 / math.pi
STIFFNESS_MAX_NM_DEG = catalog.COMMANDS["set"].arg("stiffness_nm_deg").high


def stiffness_setpoint(ctx: PlanContext, args: dict, target: Sequence[float]) -> tuple[float, ...]:
    """``stiffness_nm_deg`` [N m/deg] as a stiffness per joint [N m/rad], refused for a joint
    that takes none (a cylinder joint) and where the muscles cannot hold the target with it
    (both pressures within their range, gravity on the link): the reply names the range they can."""
    raw = args["stiffness_nm_deg"]
    values = checked_numbers("stiffness_nm_deg", raw, ctx.n) if isinstance(raw, list) else [
        checked_number("stiffness_nm_deg", raw, 0.0, STIFFNESS_MAX_NM_DEG)] * ctx.n
    out = []
    for name, muscle, q, k in zip(ctx.joint_names, ctx.muscles or [None] * ctx.n, target, values):
        if muscle is None:
            raise bad_args(f"joint {name} takes no stiffness set-point (a cylinder joint)", "stiffness_nm_deg")
        lo, hi = muscle.stiffness_range(q)
        if not (0.0 < k <= STIFFNESS_MAX_NM_DEG and lo <= k * DEG_PER_RAD <= hi):
            span = (f"{lo / DEG_PER_RAD:.3f}..{hi / DEG_PER_RAD:.3f} N m/deg" if lo <= hi else "none")
            raise CommandFailed(P.REFUSED, f"joint {name}: the muscles cannot hold {math.degrees(q):.1f} deg with a "
                                           f"stiffness of {k:g} N m/deg (they can: {span})",
                                {"reason": "stiffness", "joint": name, "stiffness_nm_deg": k,
                                 "range_nm_deg": [lo / DEG_PER_RAD, hi / DEG_PER_RAD] if lo <= hi else None})
        out.append(k * DEG_PER_RAD)
    return tuple(out)


def plan_path(ctx: PlanContext, args: dict, setpoint: list[float]) -> Plan:
    """A reference path of rig-facts §1, after an approach move to its start."""
    ctx.require_rotary("name")
    name = args["name"]  # one of PATHS: checked against the catalog by the messenger
    make, default_duration = PATHS[name]
    duration = _number("path", args, "duration_s", default_duration)
    reply = {"path": name, "duration_s": duration}
    if "duration_s" not in args and ctx.authority is not None:  # no duration asked: the thesis's, or
        shortest = ctx.authority.shortest(make(ctx.link_lengths_m, ctx.elbow, ctx.n, duration))  # the fastest
        if shortest is not None and shortest > duration:  # the rig accepts if that is beyond it
            reply["duration_s"] = duration = math.ceil(shortest * 10.0) / 10.0
            reply["stretched_from_s"] = default_duration
    path = make(ctx.link_lengths_m, ctx.elbow, ctx.n, duration)
    check_authority(ctx, f"the {name} path", path, shortest_for="duration_s")
    return after_approach(ctx, args, setpoint, path, name, reply)


def plan_waypoints(ctx: PlanContext, args: dict, setpoint: list[float]) -> Plan:
    """A path through waypoints, joint (``positions`` in each joint's unit or ``angles_deg``: one
    row per point) or Cartesian (``xy_mm``), after an approach to the first; ``durations_s[i]`` is the time from point
    i to point i + 1, with cubic time scaling on each segment."""
    # One of angles_deg or xy_mm, 2-1000 points of numbers, a duration in bounds per segment: the catalog's (the
    # messenger's); one angle per joint is the rig's
    key = next(k for k in ("positions", "angles_deg", "xy_mm") if k in args)
    if key != "positions":
        ctx.require_rotary(key)
    points = [checked_numbers(key, row, ctx.n, i) if key != "xy_mm" else [float(v) for v in row]
              for i, row in enumerate(args[key])]
    durations = [float(d) for d in args["durations_s"]]
    if key != "xy_mm":
        points = [ctx.to_si(p) for p in points]
        for p in points:
            check_limits(ctx, p)
        path = trajectory.joint_waypoints(points, durations)
    else:
        angles = [tip_angles(ctx, p, f"waypoint {i} at {p} mm: ") + setpoint[2:] for i, p in enumerate(points)]
        for q in angles:  # each point in reach first, then each inside the limits by the margin
            check_limits(ctx, q)
        path = trajectory.cartesian_waypoints(ctx.link_lengths_m, ctx.elbow, ctx.n, points, durations)
    check_authority(ctx, "the waypoint path", path, shortest_for="durations_s")
    return after_approach(ctx, args, setpoint, path, "waypoints", {"points": len(points), "duration_s": path.duration})


def plan_steps(ctx: PlanContext, args: dict, setpoint: list[float]) -> Plan:
    """A step sequence: jump to ``positions[i]`` (or ``angles_deg[i]``) and hold it ``hold_s[i]`` seconds."""
    # 1-1000 levels of numbers, one hold in bounds per level: the catalog's (the messenger's); one angle per
    # joint is the rig's
    key = "positions" if "positions" in args else "angles_deg"
    if key == "angles_deg":
        ctx.require_rotary(key)
    levels = [ctx.to_si(checked_numbers(key, row, ctx.n, i)) for i, row in enumerate(args[key])]
    holds = [float(h) for h in args["hold_s"]]
    for level in levels:
        check_limits(ctx, level)
    seq = trajectory.Steps(levels, holds)
    check_authority(ctx, "the step sequence", seq, "a level is beyond what the rig can hold there")
    return Plan(seq, "steps", {"levels": len(levels), "duration_s": seq.duration}, tuple(setpoint))


def plan_excite(ctx: PlanContext, args: dict, setpoint: list[float]) -> Plan:
    """An identification experiment (:mod:`daemon.planner.excitation`, which builds on
    :mod:`daemon.planner.plans`, not on this module)."""
    return excitation.plan_excite(ctx, args, setpoint)


PLANNERS = {"set": plan_set, "path": plan_path, "waypoints": plan_waypoints, "steps": plan_steps,
            "excite": plan_excite}


def after_approach(ctx: PlanContext, args: dict, setpoint: list[float], path: trajectory.Trajectory, name: str,
                   reply: dict) -> Plan:
    """``path`` after a joint move from the set-point to its start: in ``approach_s`` if the
    request gives it, else in the shortest feasible duration with a margin (APPROACH_MARGIN)."""
    start = path.sample(0.0)[0]
    if "approach_s" in args:
        approach = _number("path", args, "approach_s")
        chosen = False
    else:
        approach, chosen = shortest_approach(ctx, setpoint, start), True
    move = trajectory.JointMove(setpoint, start, approach)
    check_authority(ctx, "the approach to its start", move, None if approach else "the rig cannot hold the start",
                    "approach_s")
    chain = trajectory.Chain([move, path], approach_s=approach)
    where = first_outside_limits(chain.profile(), ctx.limits, ctx.joint_names)
    if where is not None:
        raise CommandFailed(P.REFUSED, where, {"reason": "limits"})
    return Plan(chain, name, {**reply, "approach_s": approach, "approach_chosen": chosen, "total_s": chain.duration},
                tuple(setpoint))


def shortest_approach(ctx: PlanContext, setpoint: list[float], start: list[float]) -> float:
    """The approach duration used when none is asked for [s], to 0.1 s (rounded up)."""
    if ctx.authority is None:
        return 3.0
    shortest = ctx.authority.shortest(trajectory.JointMove(setpoint, start, 1.0))
    if shortest is None:  # the start cannot be held: the check that follows says so
        return APPROACH_MIN_S
    return max(math.ceil(shortest * APPROACH_MARGIN * 10.0) / 10.0, APPROACH_MIN_S)


def tip_angles(ctx: PlanContext, xy_mm, what: str = "") -> list[float]:
    """The planar joints' angles [rad] that put the tip at xy_mm, or a refusal (out of reach)."""
    lengths = ctx.link_lengths_m
    try:
        return list(kinematics.inverse_2link(xy_mm[0] * 1e-3, xy_mm[1] * 1e-3, lengths[0], lengths[1], ctx.elbow))
    except ValueError as exc:
        raise CommandFailed(P.REFUSED, f"{what}{exc}", {"reason": "reach", "xy_mm": list(xy_mm)}) from None


def check_limits(ctx: PlanContext, positions: Sequence[float]) -> None:
    """A refusal naming the joint, in its unit (``angle_deg``/``limits_deg`` on a rotary joint,
    ``position_mm``/``limits_mm`` on a linear one), unless every set-point [SI] is inside its
    limits by the rig file's margin (``margin_deg``/``margin_mm``: a controller's overshoot past a
    set-point at a limit would trip the arm; refused rather than moved, so that the arm goes
    nowhere its client did not ask)."""
    margins = ctx.margins or (0.0,) * ctx.n
    for j, (name, (lo, hi), q, margin) in enumerate(zip(ctx.joint_names, ctx.limits, positions, margins)):
        if not lo + margin <= q <= hi - margin:
            unit, scale = ctx.display(j)
            what = "angle" if unit == "deg" else "position"
            data = {"reason": "limits", "joint": name, f"{what}_{unit}": q * scale,
                    f"limits_{unit}": [lo * scale, hi * scale]}
            if lo <= q <= hi:
                words, shown = ctx.margin_words(j, margin, "set-points")
                raise CommandFailed(P.REFUSED, f"joint {name} set-point {ctx.text(j, q)} is within {words}",
                                    {**data, f"margin_{unit}": shown})
            raise CommandFailed(P.REFUSED, f"joint {name} set-point {ctx.text(j, q)} is outside its limits "
                                           f"{lo * scale:.1f}..{hi * scale:.1f} {unit}", data)
