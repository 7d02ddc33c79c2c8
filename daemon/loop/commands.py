"""Command handling, the loop's side: what each request does to the loop, who may ask, and
the lease.

Handlers run at the end of a cycle in the loop's thread, so whatever they change takes
effect at the next cycle boundary, and each does bounded work whatever its arguments: the
messenger has already decoded the envelope and checked the command, its socket and its
arguments against the catalog (:mod:`daemon.wire.catalog`, :mod:`daemon.wire.routed`), so a
loop command's few small arguments are only decoded here;
anything whose cost grows with the request or the rig is handed to the worker process beside
the loop (:class:`~daemon.planner.process.Preparer`) with a deferred reply:

- motion commands (``set``, ``path``, ``waypoints``, ``steps``, ``excite``) are planned and
  checked there (:mod:`daemon.planner.commands`); the loop installs the finished plan at a cycle
  boundary, or refuses it if the reference or the state changed meanwhile (an ``abort``,
  ``estop``, ``disable``, a trip), so nothing starts that was overtaken;
- ``controller.switch``, ``controller.shadow`` and ``controller.set`` build a controller or
  derive its parameters there, ``controller.reload`` reads a controller directory's file again
  there (their handlers: :mod:`daemon.loop.controller_commands`).

Handlers change the loop only through its named controls (``enable`` ... ``set_load``,
:class:`~daemon.loop.cycle.ControlLoop`) and read it only through its view
(:class:`~daemon.loop.view.LoopView`): status and describe never wait on anything.

Anyone may read, and anyone may e-stop or abort; commands that move the arm or change what
moves it need the lease (:mod:`daemon.loop.lease`). Each request comes with who sent it
(:class:`daemon.wire.keys.Identity`: a CURVE key's name and role, or anonymous without keys), and
every event a request causes records who asked (:meth:`daemon.loop.events.EventLog.signed`).
"""
from __future__ import annotations

import dataclasses
import logging
import os
import secrets
import time
from collections.abc import Callable

from controllers.base import ParamError
from daemon.planner import commands as planner
from daemon.loop.controller_commands import ControllerCommands, in_state as _in_state
from controllers.known_load import KnownLoad
from daemon.wire import catalog
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed, bad_args
from daemon.wire.keys import ANONYMOUS, Identity
from daemon.loop.lease import Lease
from daemon.loop.timing import TimingVerdicts
from daemon.planner.process import Deferred, Preparer
from daemon.loop.safety import State
from hal.interfaces import DISPLAY

VERSION = "0.1.0"
log = logging.getLogger("pneumad")


class Commands(ControllerCommands):
    # The loop's and the planner's commands (daemon.wire.catalog) -> the method serving them;
    # a deferred command's method takes the request (its arguments are decoded beside the loop).
    HANDLERS = {
        "ping": "ping", "status": "status", "describe": "describe", "estop": "estop", "abort": "abort",
        "enable": "enable", "disable": "disable", "reset": "reset", "set": "motion", "path": "motion",
        "waypoints": "motion", "steps": "motion", "excite": "motion", "controller.list": "controller_list",
        "controller.get": "controller_get", "controller.switch": "controller_switch",
        "controller.set": "controller_set", "controller.shadow": "controller_shadow",
        "controller.commit": "controller_commit", "controller.discard": "controller_discard",
        "controller.reload": "controller_reload",
        "load.set": "load_set", "load.clear": "load_clear", "lease.acquire": "lease_acquire",
        "lease.renew": "lease_renew", "lease.release": "lease_release", "lease.revoke": "lease_revoke",
        "timing.verdict": "timing_verdict",
    }
    catalog.check_handlers(("loop", "planner"), HANDLERS)

    def __init__(self, loop, preparer: Preparer | None = None, security: dict | None = None):
        self.loop = loop
        self.security = security or {"mode": "local", "warning": None}
        self.client = ANONYMOUS  # who sent the request being handled
        self.lease = Lease(loop.handles, loop.hold, loop.disable)
        # the port's health fields of status (telemetry, helpers), where a port serves the loop
        self.port_health: Callable[[], dict] | None = None
        self.events = loop.handles.events  # the loop's event log: who asked signs what a request causes
        self.timing = TimingVerdicts(loop, loop.view, self.events)  # the messenger's verdicts on the loop's timing
        self.requests = 0
        self.errors = 0
        # Which daemon answers (ping, status): a client on a shared machine can tell its own.
        self.daemon = {"pid": os.getpid(), "started": time.time(), "instance": secrets.token_hex(8)}
        # Built once, off the loop: scanning entry points costs milliseconds.
        self.owns_preparer = preparer is None  # else whoever passed it closes it
        self.preparer = preparer or Preparer()
        self.view = loop.view  # what the handlers read; they change the loop only through its controls
        self.dirs = self.view.controller_dirs  # the controller directories' files (controllers.directory)
        self._controllers = self._describe_controllers(self.view.controller_plugins) + self.dirs.refused
        self.refused_controllers = [c for c in self._controllers if "error" in c]  # status.controllers_refused
        self.preparer.sources = self.dirs.live(type(self.view.controller))
        for refused in self.refused_controllers:  # at start-up, before the loop cycles: logged once, and an event
            log.warning("controller %s refused: %s (requests for it are refused; controller.list and status say so)",
                        refused["name"], refused["error"])
            self.events.add({"kind": "plugin", "name": refused["name"], "cause": refused["error"]})
        self.described = self._build_describe()  # what describe answers, packed once: it is large and never changes
        self._describe_packed = P.Packed.of(self.described)
        self._plan_context = planner.PlanContext.of(self.view.rig, self.view.context)
        # Parameters clients set, per controller name: a switch back to one carries them (and says so)
        self._set_before: dict[str, dict] = {}
        self._active_as = self.view.controller.name  # the name the active controller was switched in by
        self._shadow_set: tuple[str, dict] | None = None  # a shadow candidate's name and parameters, till its commit

    # -- entry points -----------------------------------------------------------------------
    def handle_request(self, request: dict, control: bool = False, client: Identity = ANONYMOUS) -> bytes | Deferred:
        """Run and encode one request from ``client``, its envelope decoded and checked by the
        messenger (:mod:`daemon.wire.routed`); every failure becomes an error reply. Work done
        off the loop comes back as a Deferred: see :meth:`complete`."""
        self.requests += 1
        self.client = client
        with self.events.signed(str(client)):
            return self._handle_request(request, control)

    def _handle_request(self, request: dict, control: bool) -> bytes | Deferred:
        request_id = request["id"]
        try:
            result = self.handle(request, control)
            if isinstance(result, Deferred):
                result.request_id, result.client = request_id, self.client
                return result
            return P.encode_result(request_id, result)
        except P.ProtocolError as exc:
            self.errors += 1
            return P.encode_error(exc.request_id, exc.code, exc.message)
        except CommandFailed as exc:
            self.errors += 1
            return P.encode_error(request_id, exc.code, exc.message, exc.data)
        except Exception as exc:  # a bug in a handler must not take the loop down
            self.errors += 1
            return P.encode_error(request_id, P.INTERNAL, f"{type(exc).__name__}: {exc}")

    def complete(self, deferred: Deferred) -> bytes:
        """The reply to a deferred command whose work is done: its result applied now, at
        this cycle boundary, or the error that stopped it."""
        with self.events.signed(str(deferred.client)):
            return self._complete(deferred)

    def _complete(self, deferred: Deferred) -> bytes:
        request_id = deferred.request_id
        data = None
        try:
            return P.encode_result(request_id, deferred.finish(deferred.future.result()))
        except CommandFailed as exc:
            message, code, data = exc.message, exc.code, exc.data
        except P.ProtocolError as exc:
            message, code = exc.message, exc.code
        except ParamError as exc:  # a parameter (controller.set), an option (a design) refused
            message, code = str(exc), P.BAD_ARGS
            argument = "params" if "parameter" in exc.data else "options" if "option" in exc.data else "name"
            data = {"argument": argument, **exc.data}  # "name": the controller cannot run on this rig
        except LookupError as exc:  # no such controller
            message, code = str(exc).strip("'\""), P.BAD_ARGS
            data = {"argument": "name", "allowed": [c["name"] for c in self._controllers]}
        except Exception as exc:  # a plugin that fails to build is refused, never fatal
            message, code = f"{type(exc).__name__}: {exc}", P.REFUSED
        self.errors += 1
        return P.encode_error(request_id, code, message, data)

    def _off_loop(self, finish, function, *args) -> Deferred:
        """Run ``function(*args)`` in the worker process; ``finish(result)`` applies it on
        the loop thread."""
        if self.preparer.busy:
            raise CommandFailed(P.BUSY, "a plan or a controller is being prepared beside the loop; send this again "
                                        "once its reply is in", {"reason": "busy"})
        return self.preparer.submit(finish, function, *args)

    def handle(self, request: dict, control: bool = False):
        """One request the messenger has checked against the catalog (command, socket,
        arguments, role), or one of its own (``catalog.INTERNAL``: only the messenger writes
        the rings, and it lets no client send those): the lease, then the command (which
        checks the state)."""
        name = request["cmd"]
        command = catalog.INTERNAL.get(name) or catalog.find(name, "control" if control else "command")
        if command.lease:
            self.lease.check(request["lease"], self.client)
        method = getattr(self, self.HANDLERS[command.name])
        if command.deferred:  # its arguments are decoded beside the loop, with its work
            return method(request)
        return method(P.decode_args(request))

    def tick(self) -> None:
        """Once a cycle: the lease's clock (:meth:`daemon.loop.lease.Lease.tick`)."""
        self.lease.tick()

    # -- lease ------------------------------------------------------------------------------
    def lease_acquire(self, args):
        return self.lease.acquire(self.client, float(args.get("ttl_s", self.lease.ttl)))

    def lease_renew(self, args):
        return self.lease.renew()

    def lease_release(self, args):
        return self.lease.release()

    def lease_revoke(self, args):
        """The messenger's word that a key left the allow-list or changed (internal, at a reload)."""
        return self.lease.revoke(args["key"], args.get("why", "removed"))

    def timing_verdict(self, args):
        """The messenger's verdict on the loop's timing (internal, every stats window)."""
        return self.timing.take(args)

    # -- reading ----------------------------------------------------------------------------
    def ping(self, args):
        return {"pong": True, "t": self.view.now(), "version": VERSION, "daemon": self.daemon}

    def status(self, args):
        fields = self.view.status()  # then the lease's, the client's and the daemon's: the catalog's fields (a test's)
        held = self.lease.held
        fields["lease_held"] = held
        fields["lease_holder"] = self.lease.holder.name if held else None
        fields["unleased_disable_in_s"] = self.lease.disable_in()
        fields["client"] = {"name": self.client.name, "role": self.client.role}
        fields["security"] = self.security
        fields["controllers_refused"] = self.refused_controllers
        fields["timing"] = self.timing.status
        fields["daemon"] = self.daemon
        if self.port_health is not None:
            fields.update(self.port_health())
        return fields

    def describe(self, args):
        return self._describe_packed  # 10-16 KiB: packing it per request cost a cycle ~100 us

    def _build_describe(self) -> dict:
        view, rig = self.view, self.view.rig
        return {
            "version": VERSION,
            "protocol": P.VERSION,
            "rig": {"name": rig.rig.name, "description": rig.rig.description, "origin": rig.origin, "hash": rig.hash,
                    "source": rig.source},
            "period_s": view.period,
            "joints": [self._describe_joint(j, margin) for j, margin in zip(rig.joints, rig.setpoint_margins)],
            "command_interfaces": [c.describe() for c in view.command_interfaces],
            "cycle_layout": view.layout.describe(),
            "cycle_layout_id": view.layout.id,
            "arm": {"link_lengths_mm": list(rig.arm.link_lengths_mm), "elbow": rig.arm.elbow},
            "limits": {"max_pressure_mpa": rig.limits.max_pressure_mpa,
                       "max_pressure_rate_mpa_s": rig.limits.max_pressure_rate_mpa_s,
                       "authority_fraction": rig.limits.authority_fraction},
            "tracking": {"error_deg": rig.safety.tracking_error_deg, "window_s": rig.safety.tracking_window_s,
                         "action": rig.safety.tracking_action, "fallback_controller": rig.safety.fallback_controller},
            "transport": {"backend": view.transport.backend, "rate_hz": view.transport.rate_hz,
                          "inputs": [[c.name, c.kind.value, c.low, c.high] for c in view.transport.inputs],
                          "outputs": [[c.name, c.kind.value, c.low, c.high] for c in view.transport.outputs]},
            "units": {"angle": "rad (deg where a key says _deg)", "u": "V (V_MV, head chamber above its bias)",
                      "pressure": "Pa", "force": "N", "time": "s"},
            "controllers": self._controllers,
            "states": [s.value for s in State],
            "commands": sorted(catalog.COMMANDS),
            "control_commands": list(catalog.served_on("control")),
            "deferred_commands": list(catalog.DEFERRED),
            "deferred_timeout_s": self.preparer.time_limit_s,
            "security": self.security,
        }

    def _describe_joint(self, j, margin: float) -> dict:
        """A joint as ``describe`` gives it: limits, the range its set-points may take (its limits
        less the rig file's set-point ``margin`` [SI], in the unit people read it in), actuation,
        its commands' ranges, safe state."""
        commands = [c for c in self.view.command_interfaces if c.joint == j.name]
        unit, scale = DISPLAY[j.position_unit]
        lo, hi = j.limits
        joint = {"name": j.name, "min_angle_deg": j.min_angle_deg, "max_angle_deg": j.max_angle_deg,
                 "max_speed_deg_s": j.max_speed_deg_s, "position_unit": unit,
                 "setpoint_range": [round((lo + margin) * scale, 9), round((hi - margin) * scale, 9)],
                 "actuation": j.actuation, "chambers": list(j.chambers),
                 "commands": [c.name for c in commands],
                 "setpoints": ["angle", "stiffness"] if j.muscles is not None else ["angle"],
                 "safe_mpa": [d.safe_mpa for d in j.pressure_outputs]}
        if j.muscles is None:
            joint["u_min_volts"], joint["u_max_volts"] = commands[0].low, commands[0].high
        if j.brake is not None:
            joint["safe_brake_nm"] = j.brake.safe_nm
        return joint

    # -- state ------------------------------------------------------------------------------
    def estop(self, args):
        """Latch the e-stop. Never refused for its arguments: the messenger passes on only ``who``,
        a string of at most 64 characters (a value that was not a string: its repr; anything else
        sent beside it is dropped). The key that sent it is recorded first. ``written_by``: the
        loop wrote the safe state (the messenger answers ``watchdog`` for an e-stop the cycle
        watchdog wrote before the loop took it: daemon.messenger.relay)."""
        said = args.get("who", "")
        who = f"{self.client.name} ({said})" if self.client.name and said else self.client.name or said
        self.loop.estop(who)
        return {"state": self.view.state.value, "written_by": "loop"}

    def abort(self, args):
        """Stop any path or move and hold the present position; a plan being prepared is
        discarded when it is done."""
        self.loop.hold()
        return {"reference": "hold"}

    def enable(self, args):
        self.timing.check_enable()
        _in_state(self.loop.enable)
        return {"state": self.view.state.value, "recover": self.view.recovery()}

    def disable(self, args):
        self.loop.disable()
        return {"state": self.view.state.value}

    def reset(self, args):
        _in_state(self.loop.reset)
        return {"state": self.view.state.value}

    # -- motion -----------------------------------------------------------------------------
    def motion(self, request: dict) -> Deferred:
        """Plan a motion command beside the loop (:mod:`daemon.planner.commands`) from the set-point in
        force now; the loop installs it at the cycle boundary after the plan is done, unless the
        reference, the state or the lease changed meanwhile (:meth:`~daemon.loop.cycle.ControlLoop.install`):
        a routine interrupted while its move was planned hands its lease back, and its move
        must not start after that."""
        self.loop.require_enabled()
        self.timing.check_motion()
        name, remaining = self.view.reference_running()
        if remaining > 0:
            raise CommandFailed(P.BAD_STATE, f"a reference ({name}) is running for {remaining:.1f} s "
                                             f"more: abort it first, or send this once it ends",
                                {"reason": "reference_running", "remaining_s": remaining})
        generation, setpoint = self.view.reference_origin()
        lease = self.lease.token  # the lease the request came under (None: unleased)

        def finish(plan: planner.Plan) -> dict:
            if self.lease.token != lease:  # handed back, lost or taken by another since: not theirs to start
                raise CommandFailed(P.BAD_STATE, "the lease this was asked under ended while it was planned (released, "
                                                 "lost or taken by another client): nothing was started",
                                    {"reason": "overtaken"})
            self.loop.install(plan)
            return {**plan.reply, "cycle": self.view.cycle, **({"recording": plan.record} if plan.record else {})}

        return self._off_loop(finish, planner.plan, self._plan_context, request, setpoint, generation)

    # -- a known load ---------------------------------------------------------------------
    def load_set(self, args):
        """Feed a known payload forward (controllers.known_load) from the next cycle, bumplessly;
        refused if the rig's joints have no model or cannot carry it in every posture."""
        mass = float(args["mass_kg"])
        com = [float(c) for c in args.get("com_mm", catalog.COMMANDS["load.set"].default("com_mm"))]
        rig = self.view.rig
        try:
            load = KnownLoad.for_rig(mass, [c * 1e-3 for c in com], self.view.context, rig.arm.link_lengths_m,
                                     rig.arm.gravity_m_s2)
        except ValueError as exc:
            raise bad_args(str(exc), "com_mm" if "centre of mass" in str(exc) else "mass_kg") from None
        self._known_load(load)
        return {"load": self.view.load(), "cycle": self.view.cycle}

    def load_clear(self, args):
        """Stop feeding a load forward (bumplessly); says whether one was."""
        had = self.view.load() is not None
        if had:
            self._known_load(None)
        return {"cleared": had, "cycle": self.view.cycle}

    def _known_load(self, load: KnownLoad | None) -> None:
        """The loop feeds ``load`` forward, and motion is planned with it."""
        self.loop.set_load(load)
        ctx = self._plan_context
        self._plan_context = dataclasses.replace(ctx, authority=dataclasses.replace(ctx.authority, load=load))

