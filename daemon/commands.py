"""Command handling: what each request does to the loop, who may ask, and the lease.

Handlers run at the end of a cycle in the loop's thread, so whatever they change takes
effect at the next cycle boundary. Status and describe are built from the loop's last
cycle record and the static rig description; they never wait on anything.

One controlling client holds a lease (a token) and must renew it within its time to live;
commands that move the arm or change what moves it need the token. Anyone may read, and
anyone may e-stop or abort. A lease that lapses while the arm is enabled trips it.
"""
from __future__ import annotations

import math
import secrets

from controllers import registry, trajectory
from controllers.base import ParamError
from controllers.feasibility import Authority, Infeasible
from daemon import protocol as P
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
    value = args.get(key, default)
    if value is None:
        raise bad_args(f"'{key}' is required")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise bad_args(f"'{key}' must be a finite number, got {value!r}")
    if not low <= value <= high:
        raise bad_args(f"'{key}' = {value} is outside {low}..{high}")
    return float(value)


def numbers(args: dict, key: str, n: int) -> list[float]:
    value = args.get(key)
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
        "controller.list": ("controller_list", False, False),
        "controller.get": ("controller_get", False, False),
        "controller.switch": ("controller_switch", True, False),
        "controller.set": ("controller_set", True, False),
        "lease.acquire": ("lease_acquire", False, False),
        "lease.renew": ("lease_renew", True, False),
        "lease.release": ("lease_release", True, False),
    }

    def __init__(self, loop):
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

    # -- entry points -----------------------------------------------------------------------
    def handle_payload(self, payload: bytes, control: bool = False) -> bytes:
        """Decode, run and encode one request; every failure becomes an error reply."""
        self.requests += 1
        request_id = None
        try:
            request = P.decode_request(payload)
            request_id = request["id"]
            return P.encode_result(request_id, self.handle(request, control))
        except P.ProtocolError as exc:
            self.errors += 1
            return P.encode_error(exc.request_id, exc.code, exc.message)
        except CommandFailed as exc:
            self.errors += 1
            return P.encode_error(request_id, exc.code, exc.message)
        except Exception as exc:  # a bug in a handler must not take the loop down
            self.errors += 1
            return P.encode_error(request_id, P.INTERNAL, f"{type(exc).__name__}: {exc}")

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
            x, y = numbers(args, "xy_mm", 2)
            lengths = loop.rig.arm.link_lengths_m
            try:
                q = kinematics.inverse_2link(x * 1e-3, y * 1e-3, lengths[0], lengths[1], loop.rig.arm.elbow)
            except ValueError as exc:
                raise CommandFailed(P.REFUSED, str(exc)) from None
            target = list(q) + list(loop.reference[0][2:])
        for j, q in zip(loop.rig.joints, target):
            lo, hi = j.limits_rad
            if not lo <= q <= hi:
                raise CommandFailed(P.REFUSED, f"joint {j.name} set-point {math.degrees(q):.2f} deg is outside its "
                                               f"limits {j.min_angle_deg}..{j.max_angle_deg} deg")
        move = self._feasible("the move", lambda d: trajectory.JointMove(loop.reference[0], target, d), duration)
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
        return {"path": name, "duration_s": duration, "approach_s": approach, "total_s": chain.duration}

    def _feasible(self, what: str, make, duration: float):
        """``make(duration)`` if the rig's authority can deliver it, else a refusal with the
        numbers and the shortest duration that would do (rig-facts §1 "Authority")."""
        if self._authority is None or duration == 0.0:
            return make(duration)
        try:
            return self._authority.check(make, duration)
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

    def controller_switch(self, args):
        only(args, "name", "params")
        name = args.get("name")
        if not isinstance(name, str):
            raise bad_args("'name' must be a controller name")
        params = args.get("params", {})
        if not isinstance(params, dict):
            raise bad_args("'params' must be a map")
        try:
            new = registry.build(name, self.loop.context, params)
        except (LookupError, ParamError) as exc:
            raise bad_args(str(exc)) from None
        except Exception as exc:
            raise CommandFailed(P.REFUSED, f"controller {name!r} failed to build: {type(exc).__name__}: {exc}") from None
        self.loop.switch_controller(new)
        return {"active": new.name, "params": new.get_params()}

    def controller_set(self, args):
        only(args, "params")
        params = args.get("params")
        if not isinstance(params, dict) or not params:
            raise bad_args("'params' must be a non-empty map")
        c = self.loop.controller
        try:
            prepared = c.prepare_params(params)
        except ParamError as exc:
            raise bad_args(str(exc)) from None
        c.apply_params(prepared)
        return {"name": c.name, "params": c.get_params()}
