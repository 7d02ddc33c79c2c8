"""A read-only view of the loop, what status, describe and the replies read: the loop's state
interface. It reads the very fields the cycle keeps and telemetry sends, when asked, so no
cycle pays for a copy."""
from __future__ import annotations

import math

from daemon.service import realtime


class LoopView:
    def __init__(self, loop):
        self._loop = loop
        self._commands_of: list[list[tuple[str, int]]] | None = None  # per joint: (command, its index in u)
        self._outputs_of: list[list[tuple[str, int]]] = []  # per joint: (output channel, its index in the sweep)

    # -- what the loop runs on (fixed once it is built) -----------------------------------
    @property
    def rig(self):
        return self._loop.rig

    @property
    def context(self):
        """The controllers' build context (controllers.base)."""
        return self._loop.context

    @property
    def controller_plugins(self) -> dict[str, str]:
        return self._loop.controller_plugins

    @property
    def period(self) -> float:
        return self._loop.period

    @property
    def layout(self):
        """The cycle record's layout (daemon.wire.cycle_layout)."""
        return self._loop.layout

    @property
    def command_interfaces(self):
        return self._loop.actuation.commands

    @property
    def transport(self):
        return self._loop.io.transport

    # -- its state now --------------------------------------------------------------------
    def now(self) -> float:
        return self._loop.clock.now()

    @property
    def cycle(self) -> int:
        return self._loop.cycle

    @property
    def state(self):
        return self._loop.supervisor.state

    @property
    def enabled(self) -> bool:
        return self._loop.supervisor.enabled

    @property
    def controller(self):
        """The active controller (read its name and parameters; change it through the controls)."""
        return self._loop.controller

    @property
    def shadowing(self) -> bool:
        return self._loop.shadow_run is not None

    def reference_origin(self) -> tuple[int, list[float]]:
        """What a plan starts from: the reference generation and the set-point in force [rad]."""
        return self._loop.trajectory_generation, list(self._loop.reference[0])

    def reference_running(self) -> tuple[str, float]:
        """The reference's name and how long it runs on [s] (0 once ended, or for a hold)."""
        return self._loop.trajectory_name, self._loop.reference_remaining()

    def recovery(self) -> dict | None:
        """Joints enabled outside their limits on their way back, as enabled
        (:meth:`daemon.loop.recovery.Recovery.describe`), or None."""
        recovery = self._loop.supervisor.recovery
        return None if recovery is None else recovery.summary

    def load(self) -> dict | None:
        """The known load fed forward and its feed-forward per joint [V], or None."""
        ff = self._loop.feed_forward
        if ff.load is None:
            return None
        return {**ff.load.describe(), "feedforward_volts": dict(zip(self._loop.io.joint_names, ff.volts))}

    def status(self) -> dict:
        """The loop's fields of ``status`` (the lease's, the client's and the daemon's are the
        handler's)."""
        loop = self._loop
        enabled, snap = loop.supervisor.enabled, loop.snapshot
        return {
            "state": loop.supervisor.state.value,
            "cause": loop.supervisor.cause,
            "cycle": loop.cycle,
            "t": loop.clock.now(),
            "controller": loop.controller.name,
            "shadow": loop.shadow_run.summary() if loop.shadow_run is not None else None,
            "reference": loop.trajectory_name if enabled else None,
            "reference_remaining_s": loop.reference_remaining() if enabled else 0.0,
            "joints": {name: self._joint(i) for i, name in enumerate(loop.io.joint_names)},
            "force_n": None if loop.force != loop.force else loop.force,
            "faults": list(snap.faults) if snap is not None else [],
            "trips": loop.supervisor.trips,
            "overruns_total": loop.stats.overruns_total,
            "scheduling": realtime.describe(),  # the loop thread's, as the system granted it
            "load": self.load(),
            "transport": vars(loop.io.transport.health()),
            "telemetry": loop.server.telemetry_health() if loop.server is not None else None,
            "helpers": loop.server.helpers_health() if loop.server is not None else None,
            "model": loop.server.model_status() if loop.server is not None else None,
        }

    def _joint(self, i: int) -> dict:
        """One joint in ``status``: angle, set-point, speed, and its commands in force (V_MV as
        ``u_volts``; a muscle pair's pressures [Pa] and brake [N m], its stiffness set-point
        and measured pressures); ``output``: ``controller``, or ``safe state`` outside
        ``enabled``, where the safe state is written and no command is in force (null); and
        ``written_volts``, the joint's output channels as last written [V]."""
        loop = self._loop
        if self._commands_of is None:  # the command interfaces and channels are fixed once the loop is built
            self._commands_of = [[(c.name, k) for k, c in enumerate(loop.actuation.commands) if c.joint == joint]
                                 for joint in loop.io.joint_names]
            names = [ch.name for ch in loop.io.transport.outputs]
            self._outputs_of = [[(ch, names.index(ch)) for ch in channels] for channels in loop.io.joint_outputs]
        safe = not loop.supervisor.enabled
        written = loop.io.last_volts
        out = {"angle_deg": math.degrees(loop.angles[i]), "setpoint_deg": math.degrees(loop.reference[0][i]),
               "velocity_deg_s": math.degrees(loop.velocities[i]), "output": "safe state" if safe else "controller",
               "written_volts": {ch: written[k] for ch, k in self._outputs_of[i]}}
        u = loop.u
        commands = {name: None if safe else u[k] for name, k in self._commands_of[i]}
        if "v_mv" in commands:
            out["u_volts"] = commands["v_mv"]
        else:
            k = loop.stiffness[i]
            out["commands"] = commands
            out["stiffness_nm_deg"] = None if k != k else math.radians(k)
            pressures = loop.pressures[2 * i:2 * i + 2]
            out["pressures_pa"] = [None if p != p else p for p in pressures]
        return out
