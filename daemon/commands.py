"""Command handling: what each request does to the loop, who may ask, and the lease.

Handlers run at the end of a cycle in the loop's thread, so whatever they change takes
effect at the next cycle boundary. Status and describe are built from the loop's last
cycle record and the static rig description; they never wait on anything. Building a
controller or deriving new parameters is slow, so those commands hand the work to the
:class:`~daemon.preparation.Preparer` and reply when it is done and swapped in (a
:class:`~daemon.preparation.Deferred` reply).

One controlling client holds a lease (a token) and must renew it within its time to live;
commands that move the arm or change what moves it need the token. Anyone may read, and
anyone may e-stop or abort. A lease that lapses while the arm is enabled trips it.
"""
from __future__ import annotations

import math
import secrets

from controllers import registry, signals, trajectory
from controllers.base import ParamError
from controllers.feasibility import Authority, Infeasible
from daemon import protocol as P
from daemon.preparation import Deferred, Preparer
from daemon.safety import State, StateError
from hal import kinematics

VERSION = "0.1.0"


class CommandFailed(Exception):
    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code, self.message = code, message


def bad_args(message: str) -> CommandFailed:
    return CommandFailed(P.BAD_ARGS, message)


def number(args: dict, key: str, low: float, high: float, default: float | None = None) -> float:
    return checked_number(key, args.get(key, default), low, high)


def checked_number(key: str, value, low: float, high: float) -> float:
    """``value`` as a float in low..high, or a bad_args error naming ``key``."""
    if value is None:
        raise bad_args(f"'{key}' is required")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise bad_args(f"'{key}' must be a finite number, got {value!r}")
    if not low <= value <= high:
        raise bad_args(f"'{key}' = {value} is outside {low}..{high}")
    return float(value)


def integer(args: dict, key: str, low: int, high: int, default: int) -> int:
    value = args.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise bad_args(f"'{key}' must be a whole number, got {value!r}")
    if not low <= value <= high:
        raise bad_args(f"'{key}' = {value} is outside {low}..{high}")
    return value


def numbers(args: dict, key: str, n: int) -> list[float]:
    return checked_numbers(key, args.get(key), n)


def checked_numbers(key: str, value, n: int) -> list[float]:
    """``value`` as a list of n finite floats, or a bad_args error naming ``key``."""
    if not isinstance(value, list) or len(value) != n:
        raise bad_args(f"'{key}' must be a list of {n} numbers")
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise bad_args(f"'{key}' must hold finite numbers, got {v!r}")
    return [float(v) for v in value]


def only(args: dict, *allowed: str) -> None:
    unknown = set(args) - set(allowed)
    if unknown:
        raise bad_args(f"unknown argument {sorted(map(str, unknown))[0]!r} (allowed: {', '.join(allowed) or 'none'})")


class Commands:
    # name -> (method, needs the lease, allowed on the control socket)
    TABLE = {
        "ping": ("ping", False, True),
        "status": ("status", False, True),
        "describe": ("describe", False, False),
        "estop": ("estop", False, True),
        "abort": ("abort", False, True),
        "enable": ("enable", True, False),
        "disable": ("disable", True, True),
        "reset": ("reset", True, False),
        "set": ("set_point", True, False),
        "path": ("path", True, False),
        "waypoints": ("waypoints", True, False),
        "steps": ("steps", True, False),
        "excite": ("excite", True, False),
        "controller.list": ("controller_list", False, False),
        "controller.get": ("controller_get", False, False),
        "controller.switch": ("controller_switch", True, False),
        "controller.set": ("controller_set", True, False),
        "controller.shadow": ("controller_shadow", True, False),
        "controller.commit": ("controller_commit", True, False),
        "controller.discard": ("controller_discard", True, False),
        "lease.acquire": ("lease_acquire", False, False),
        "lease.renew": ("lease_renew", True, False),
        "lease.release": ("lease_release", True, False),
    }

    def __init__(self, loop, preparer: Preparer | None = None):
        self.loop = loop
        self.lease: str | None = None
        self.lease_expires = 0.0
        self.lease_ttl = loop.rig.safety.lease_ttl_s
        self.lease_ttl_active = self.lease_ttl
        self.requests = 0
        self.errors = 0
        # Built once, off the loop: scanning entry points costs milliseconds.
        self._controllers = self._describe_controllers()
        self._describe = self._build_describe()
        models_known = all(m is not None for m in loop.context.models)
        self._authority = Authority.of(loop.rig, loop.context, loop.rig.limits.authority_fraction) if models_known else None
        self.preparer = preparer or Preparer()

    # -- entry points -----------------------------------------------------------------------
    def handle_payload(self, payload: bytes, control: bool = False) -> bytes | Deferred:
        """Decode, run and encode one request; every failure becomes an error reply. Work
        done off the loop comes back as a Deferred: see :meth:`complete`."""
        self.requests += 1
        request_id = None
        try:
            request = P.decode_request(payload)
            request_id = request["id"]
            result = self.handle(request, control)
            if isinstance(result, Deferred):
                result.request_id = request_id
                return result
            return P.encode_result(request_id, result)
        except P.ProtocolError as exc:
            self.errors += 1
            return P.encode_error(exc.request_id, exc.code, exc.message)
        except CommandFailed as exc:
            self.errors += 1
            return P.encode_error(request_id, exc.code, exc.message)
        except Exception as exc:  # a bug in a handler must not take the loop down
            self.errors += 1
            return P.encode_error(request_id, P.INTERNAL, f"{type(exc).__name__}: {exc}")

    def complete(self, deferred: Deferred) -> bytes:
        """The reply to a deferred command whose work is done: its result applied now, at
        this cycle boundary, or the error that stopped it."""
        request_id = deferred.request_id
        try:
            return P.encode_result(request_id, deferred.finish(deferred.future.result()))
        except CommandFailed as exc:
            message, code = exc.message, exc.code
        except (LookupError, ParamError) as exc:
            message, code = str(exc).strip("'\""), P.BAD_ARGS
        except Exception as exc:  # a plugin that fails to build is refused, never fatal
            message, code = f"{type(exc).__name__}: {exc}", P.REFUSED
        self.errors += 1
        return P.encode_error(request_id, code, message)

    def _off_loop(self, finish, function, *args) -> Deferred:
        """Run ``function(*args)`` in the worker process; ``finish(result)`` applies it on
        the loop thread."""
        if self.preparer.busy:
            raise CommandFailed(P.BUSY, "a controller is being prepared; send this again once its reply is in")
        return self.preparer.submit(finish, function, *args)

    def handle(self, request: dict, control: bool = False):
        entry = self.TABLE.get(request["cmd"])
        if entry is None:
            raise CommandFailed(P.UNKNOWN_COMMAND, f"unknown command {request['cmd']!r} "
                                                   f"(known: {', '.join(sorted(self.TABLE))})")
        method, needs_lease, on_control = entry
        if control and not on_control:
            raise CommandFailed(P.BAD_ARGS, f"{request['cmd']!r} is not served on the control socket")
        if needs_lease:
            self._check_lease(request["lease"])
        return getattr(self, method)(request["args"])

    def tick(self) -> None:
        """Once a cycle: a lease that lapsed while the arm was enabled trips it."""
        if self.lease is not None and self.loop.clock.now() > self.lease_expires:
            self.lease = None
            if self.loop.supervisor.enabled:
                self.loop.supervisor.trip("lease lost: the controlling client stopped renewing it")

    def _check_lease(self, token) -> None:
        if self.lease is None:
            raise CommandFailed(P.NO_LEASE, "this command needs the lease: send lease.acquire first")
        if token != self.lease:
            raise CommandFailed(P.NO_LEASE, "another client holds the lease; this command needs it")

    # -- lease ------------------------------------------------------------------------------
    def lease_acquire(self, args):
        only(args, "ttl_s")
        ttl = number(args, "ttl_s", 0.1, 60.0, self.lease_ttl)
        if self.lease is not None:
            raise CommandFailed(P.LEASE_HELD, f"another client holds the lease for up to "
                                              f"{self.lease_expires - self.loop.clock.now():.1f} s more")
        self.lease = secrets.token_hex(16)
        self.lease_ttl_active = ttl
        self.lease_expires = self.loop.clock.now() + ttl
        return {"lease": self.lease, "ttl_s": ttl}

    def lease_renew(self, args):
        only(args)
        self.lease_expires = self.loop.clock.now() + self.lease_ttl_active
        return {"ttl_s": self.lease_ttl_active}

    def lease_release(self, args):
        only(args)
        self.lease = None
        return {}

    # -- reading ----------------------------------------------------------------------------
    def ping(self, args):
        return {"pong": True, "t": self.loop.clock.now(), "version": VERSION}

    def status(self, args):
        loop = self.loop
        snap = loop.snapshot
        return {
            "state": loop.state.value,
            "cause": loop.supervisor.cause,
            "cycle": loop.cycle,
            "t": loop.clock.now(),
            "controller": loop.controller.name,
            "shadow": loop.shadow.summary() if loop.shadow is not None else None,
            "reference": loop.trajectory_name,
            "joints": {name: {"angle_deg": math.degrees(q), "setpoint_deg": math.degrees(r),
                              "velocity_deg_s": math.degrees(w), "u_volts": u}
                       for name, q, r, w, u in zip(loop.io.joint_names, loop.angles, loop.reference[0],
                                                   loop.velocities, loop.u)},
            "force_n": None if loop.force != loop.force else loop.force,
            "faults": list(snap.faults) if snap is not None else [],
            "lease_held": self.lease is not None,
            "trips": loop.supervisor.trips,
            "overruns_total": loop.stats.overruns_total,
            "transport": vars(loop.io.transport.health()),
            "telemetry": loop.server.telemetry_health() if loop.server is not None else None,
        }

    def describe(self, args):
        return self._describe

    def _build_describe(self) -> dict:
        loop, rig = self.loop, self.loop.rig
        return {
            "version": VERSION,
            "protocol": P.VERSION,
            "rig": {"name": rig.rig.name, "description": rig.rig.description, "origin": rig.origin, "hash": rig.hash,
                    "source": rig.source},
            "period_s": loop.period,
            "joints": [{"name": j.name, "min_angle_deg": j.min_angle_deg, "max_angle_deg": j.max_angle_deg,
                        "max_speed_deg_s": j.max_speed_deg_s, "u_min_volts": lo, "u_max_volts": hi,
                        "safe_mpa": [j.head.safe_mpa, j.rod.safe_mpa]}
                       for j, lo, hi in zip(rig.joints, loop.actuation.u_min, loop.actuation.u_max)],
            "arm": {"link_lengths_mm": list(rig.arm.link_lengths_mm), "elbow": rig.arm.elbow},
            "limits": {"max_pressure_mpa": rig.limits.max_pressure_mpa,
                       "max_pressure_rate_mpa_s": rig.limits.max_pressure_rate_mpa_s},
            "transport": {"backend": loop.io.transport.backend, "rate_hz": loop.io.transport.rate_hz,
                          "inputs": [[c.name, c.kind.value, c.low, c.high] for c in loop.io.transport.inputs],
                          "outputs": [[c.name, c.kind.value, c.low, c.high] for c in loop.io.transport.outputs]},
            "units": {"angle": "rad (deg where a key says _deg)", "u": "V (V_MV, head chamber above its bias)",
                      "pressure": "Pa", "force": "N", "time": "s"},
            "controllers": self._controllers,
            "states": [s.value for s in State],
            "commands": sorted(self.TABLE),
        }

    # -- state ------------------------------------------------------------------------------
    def estop(self, args):
        self.loop.estop(str(args.get("who", ""))[:64])
        return {"state": self.loop.state.value}

    def abort(self, args):
        """Stop any path or move and hold the present position."""
        self.loop.hold_position()
        return {"reference": "hold"}

    def enable(self, args):
        only(args)
        try:
            self.loop.enable()
        except StateError as exc:
            raise CommandFailed(P.BAD_STATE, str(exc)) from None
        return {"state": self.loop.state.value}

    def disable(self, args):
        only(args)
        self.loop.disable()
        return {"state": self.loop.state.value}

    def reset(self, args):
        only(args)
        try:
            self.loop.reset()
        except StateError as exc:
            raise CommandFailed(P.BAD_STATE, str(exc)) from None
        return {"state": self.loop.state.value}

    # -- motion -----------------------------------------------------------------------------
    def set_point(self, args):
        """Move to joint angles (``angles_deg`` or ``angles_rad``) or a tip point (``xy_mm``),
        in ``duration_s`` with cubic time scaling (0: a step)."""
        only(args, "angles_deg", "angles_rad", "xy_mm", "duration_s")
        loop = self.loop
        given = [k for k in ("angles_deg", "angles_rad", "xy_mm") if k in args]
        if len(given) != 1:
            raise bad_args("give exactly one of angles_deg, angles_rad, xy_mm")
        duration = number(args, "duration_s", 0.0, 3600.0, 0.0)
        if given[0] == "angles_deg":
            target = [math.radians(a) for a in numbers(args, "angles_deg", loop.n)]
        elif given[0] == "angles_rad":
            target = numbers(args, "angles_rad", loop.n)
        else:
            target = self._tip_angles(numbers(args, "xy_mm", 2)) + list(loop.reference[0][2:])
        self._check_limits(target)
        move = self._feasible("the move", lambda d: trajectory.JointMove(loop.reference[0], target, d), duration,
                              fixed=None if duration else "the rig cannot hold that angle")
        self._require_enabled()
        loop.set_trajectory(move, "set")
        return {"target_deg": [math.degrees(q) for q in target], "duration_s": duration, "cycle": loop.cycle}

    def path(self, args):
        """Run a reference path of rig-facts §1, after an approach move to its start."""
        only(args, "name", "duration_s", "approach_s")
        loop = self.loop
        name = args.get("name")
        makers = {"translation": (trajectory.translation, 15.0), "circle": (trajectory.circle, 20.0)}
        if name not in makers:
            raise bad_args(f"'name' must be one of {', '.join(makers)}, got {name!r}")
        make, default_duration = makers[name]
        duration = number(args, "duration_s", 0.5, 3600.0, default_duration)
        approach = number(args, "approach_s", 0.0, 600.0, 3.0)
        lengths, elbow = loop.rig.arm.link_lengths_m, loop.rig.arm.elbow
        path = self._feasible(f"the {name} path", lambda d: make(lengths, elbow, loop.n, d), duration)
        return self._start_after_approach(path, name, approach, {"path": name, "duration_s": duration})

    def waypoints(self, args):
        """A path through waypoints, joint (``angles_deg``: one row per point) or Cartesian
        (``xy_mm``), after an approach to the first; ``durations_s[i]`` is the time from point
        i to point i + 1, with cubic time scaling on each segment."""
        only(args, "angles_deg", "xy_mm", "durations_s", "approach_s")
        loop = self.loop
        given = [k for k in ("angles_deg", "xy_mm") if k in args]
        if len(given) != 1:
            raise bad_args("give exactly one of angles_deg (joint waypoints) or xy_mm (Cartesian waypoints)")
        rows = args[given[0]]
        if not isinstance(rows, list) or not 2 <= len(rows) <= 1000:
            raise bad_args(f"'{given[0]}' must be a list of 2 to 1000 points")
        width = loop.n if given[0] == "angles_deg" else 2
        points = [checked_numbers(f"{given[0]}[{i}]", row, width) for i, row in enumerate(rows)]
        durations = args.get("durations_s")
        if not isinstance(durations, list) or len(durations) != len(points) - 1:
            raise bad_args(f"'durations_s' must list {len(points) - 1} segment durations (one fewer than points)")
        durations = [checked_number(f"durations_s[{i}]", d, 0.01, 3600.0) for i, d in enumerate(durations)]
        approach = number(args, "approach_s", 0.0, 600.0, 3.0)
        total = sum(durations)
        if given[0] == "angles_deg":
            points = [[math.radians(a) for a in p] for p in points]
            for p in points:
                self._check_limits(p)

            def make(d):
                return trajectory.joint_waypoints(points, [x * d / total for x in durations])
        else:
            lengths, elbow = loop.rig.arm.link_lengths_m, loop.rig.arm.elbow
            for p in points:
                self._tip_angles(p, f"waypoint {p} mm: ")

            def make(d):
                return trajectory.cartesian_waypoints(lengths, elbow, loop.n, points, [x * d / total for x in durations])
        path = self._feasible("the waypoint path", make, total)
        return self._start_after_approach(path, "waypoints", approach, {"points": len(points), "duration_s": total})

    def steps(self, args):
        """A step sequence: jump to ``angles_deg[i]`` and hold it ``hold_s[i]`` seconds."""
        only(args, "angles_deg", "hold_s")
        loop = self.loop
        rows, holds = args.get("angles_deg"), args.get("hold_s")
        if not isinstance(rows, list) or not 1 <= len(rows) <= 1000:
            raise bad_args("'angles_deg' must be a list of 1 to 1000 levels, one angle per joint each")
        if not isinstance(holds, list) or len(holds) != len(rows):
            raise bad_args("'hold_s' must give one hold time per level")
        levels = [[math.radians(a) for a in checked_numbers(f"angles_deg[{i}]", row, loop.n)]
                  for i, row in enumerate(rows)]
        holds = [checked_number(f"hold_s[{i}]", h, 0.001, 3600.0) for i, h in enumerate(holds)]
        for level in levels:
            self._check_limits(level)
        seq = self._feasible("the step sequence", lambda d: trajectory.Steps(levels, holds), sum(holds),
                             fixed="a level is beyond what the rig can hold there")
        self._require_enabled()
        loop.set_trajectory(seq, "steps")
        return {"levels": len(levels), "duration_s": seq.duration, "cycle": loop.cycle}

    def excite(self, args):
        """An identification signal on one joint's reference about its present set-point:
        ``signal`` chirp (``f0_hz``, ``f1_hz``, ``duration_s``) or prbs (``order``, ``bit_s``,
        ``periods``), of ``amplitude_deg``; the other joints hold."""
        loop = self.loop
        joint = args.get("joint")
        if joint not in loop.io.joint_names:
            raise bad_args(f"'joint' must be one of {', '.join(loop.io.joint_names)}, got {joint!r}")
        j = loop.io.joint_names.index(joint)
        amplitude = math.radians(number(args, "amplitude_deg", 0.01, 45.0))
        base = list(loop.reference[0])
        signal = args.get("signal")
        if signal == "chirp":
            only(args, "signal", "joint", "amplitude_deg", "f0_hz", "f1_hz", "duration_s")
            f0 = number(args, "f0_hz", 0.001, 100.0, 0.1)
            f1 = number(args, "f1_hz", 0.001, 100.0, 1.0)
            if f1 <= f0:
                raise bad_args(f"'f1_hz' ({f1}) must be above 'f0_hz' ({f0})")
            duration = number(args, "duration_s", 1.0, 3600.0, 60.0)
            excitation = signals.LogChirp(base, j, amplitude, f0, f1, duration)
        elif signal == "prbs":
            only(args, "signal", "joint", "amplitude_deg", "order", "bit_s", "periods")
            excitation = signals.PRBS(base, j, amplitude, integer(args, "order", 2, 16, 8),
                                      number(args, "bit_s", 0.001, 60.0, 0.2), integer(args, "periods", 1, 100, 1))
        else:
            raise bad_args(f"'signal' must be chirp or prbs, got {signal!r}")
        lo, hi = loop.rig.joints[j].limits_rad
        if not (lo <= base[j] - amplitude and base[j] + amplitude <= hi):
            raise CommandFailed(P.REFUSED, f"joint {joint} at {math.degrees(base[j]):.1f} deg +- "
                                           f"{math.degrees(amplitude):.1f} deg leaves its limits "
                                           f"{math.degrees(lo):.1f}..{math.degrees(hi):.1f} deg")
        self._feasible(f"the {signal}", lambda d: excitation, excitation.duration,
                       fixed="lower the amplitude" + (" or the top frequency" if signal == "chirp" else ""))
        self._require_enabled()
        loop.set_trajectory(excitation, signal)
        return {"signal": signal, "joint": joint, "duration_s": excitation.duration, "cycle": loop.cycle}

    def _start_after_approach(self, path, name: str, approach: float, reply: dict) -> dict:
        """Follow ``path`` after a feasible joint move from the present set-point to its start."""
        loop = self.loop
        start = path.sample(0.0)[0]
        move = self._feasible("the approach to its start", lambda d: trajectory.JointMove(loop.reference[0], start, d),
                              approach)
        chain = trajectory.Chain([move, path])
        try:
            trajectory.check_within_limits(chain, [j.limits_rad for j in loop.rig.joints], loop.io.joint_names)
        except ValueError as exc:
            raise CommandFailed(P.REFUSED, str(exc)) from None
        self._require_enabled()
        loop.set_trajectory(chain, name)
        return {**reply, "approach_s": approach, "total_s": chain.duration}

    def _tip_angles(self, xy_mm, what: str = "") -> list[float]:
        """The planar joints' angles [rad] that put the tip at xy_mm, or a refusal (out of reach)."""
        arm = self.loop.rig.arm
        lengths = arm.link_lengths_m
        try:
            return list(kinematics.inverse_2link(xy_mm[0] * 1e-3, xy_mm[1] * 1e-3, lengths[0], lengths[1], arm.elbow))
        except ValueError as exc:
            raise CommandFailed(P.REFUSED, f"{what}{exc}") from None

    def _check_limits(self, angles) -> None:
        for j, q in zip(self.loop.rig.joints, angles):
            lo, hi = j.limits_rad
            if not lo <= q <= hi:
                raise CommandFailed(P.REFUSED, f"joint {j.name} set-point {math.degrees(q):.2f} deg is outside its "
                                               f"limits {j.min_angle_deg}..{j.max_angle_deg} deg")

    def _feasible(self, what: str, make, duration: float, fixed: str | None = None):
        """``make(duration)`` if the rig's authority can deliver it, else a refusal with the
        numbers and the shortest duration that would do (rig-facts §1 "Authority"); see
        :meth:`Authority.check` for ``fixed``."""
        if self._authority is None:
            return make(duration)
        try:
            return self._authority.check(make, duration, fixed=fixed)
        except Infeasible as exc:
            raise CommandFailed(P.REFUSED, f"{what} in {duration:g} s is {exc}") from None

    def _require_enabled(self):
        if not self.loop.supervisor.enabled:
            raise CommandFailed(P.BAD_STATE, f"the arm is {self.loop.state.value}: enable it first")

    # -- controllers ------------------------------------------------------------------------
    def controller_list(self, args):
        return {"active": self.loop.controller.name, "available": self._controllers}

    @staticmethod
    def _describe_controllers() -> list[dict]:
        available = []
        for name in registry.available():
            try:
                available.append(registry.load(name).describe())
            except LookupError as exc:
                available.append({"name": name, "error": str(exc)})
        return available

    def controller_get(self, args):
        only(args)
        c = self.loop.controller
        return {"name": c.name, "params": c.get_params(), "spec": [p.describe() for p in c.params]}

    def _candidate_args(self, args) -> tuple[str, dict, dict]:
        only(args, "name", "params", "options")
        name = args.get("name")
        if not isinstance(name, str):
            raise bad_args("'name' must be a controller name")
        params, options = args.get("params", {}), args.get("options", {})
        if not isinstance(params, dict) or not isinstance(options, dict):
            raise bad_args("'params' and 'options' must be maps")
        return name, params, options

    def controller_switch(self, args):
        """Build a controller off the loop, then swap it in at a cycle boundary (bumpless)."""
        name, params, options = self._candidate_args(args)

        def finish(new):
            self.loop.switch_controller(new)
            return {"active": new.name, "params": new.get_params(), "cycle": self.loop.cycle}

        return self._off_loop(finish, registry.build, name, self.loop.context, params, options)

    def controller_set(self, args):
        """Validate and derive a parameter change off the loop; apply it at a cycle boundary."""
        only(args, "params")
        params = args.get("params")
        if not isinstance(params, dict) or not params:
            raise bad_args("'params' must be a non-empty map")
        c = self.loop.controller

        def finish(prepared):
            if self.loop.controller is not c:
                raise CommandFailed(P.REFUSED, f"the controller changed to {self.loop.controller.name} while the "
                                               f"change for {c.name} was prepared; nothing was applied")
            c.apply_params(prepared)
            return {"name": c.name, "params": c.get_params(), "cycle": self.loop.cycle}

        return self._off_loop(finish, registry.prepare_change, type(c), c.context, c.given_options,
                              c.get_params(), params)

    def controller_shadow(self, args):
        """Build a candidate off the loop and run it beside the active controller, unapplied."""
        name, params, options = self._candidate_args(args)

        def finish(candidate):
            self.loop.start_shadow(candidate)
            return {"shadow": candidate.name, "active": self.loop.controller.name, "cycle": self.loop.cycle}

        return self._off_loop(finish, registry.build, name, self.loop.context, params, options)

    def controller_commit(self, args):
        """Make the shadow candidate the active controller (bumpless); the run's comparison."""
        only(args)
        if self.loop.shadow is None:
            raise CommandFailed(P.BAD_STATE, "no shadow run to commit: start one with controller.shadow")
        return {**self.loop.commit_shadow(), "active": self.loop.controller.name, "cycle": self.loop.cycle}

    def controller_discard(self, args):
        """End the shadow run without applying it; the run's comparison."""
        only(args)
        if self.loop.shadow is None:
            raise CommandFailed(P.BAD_STATE, "no shadow run to discard")
        return self.loop.end_shadow("discard")
