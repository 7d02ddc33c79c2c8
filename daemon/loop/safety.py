"""The safety supervisor: the daemon's states, its trips, and the limits on every command.

States: STARTING -> IDLE <-> ENABLED; any trip -> FAULT, an e-stop -> ESTOP, both latched
until an explicit reset. Outside ENABLED the loop writes the rig's configured safe state
every cycle, whatever a controller last asked for. The safe state is a commanded pressure
pair per joint (default: vent), not "power off": an ITV0051 that loses its 24 V supply
does not reliably vent.

Trips carry a cause in plain words. Sensor and speed checks trip only after
``bad_samples_to_trip`` bad samples in a row, so one noisy sample is not a fault.
"""
from __future__ import annotations

from hal.config import RigConfig

from daemon.wire.states import State
from daemon.loop.events import EventLog
from daemon.loop.recovery import Recovery


class StateError(RuntimeError):
    """A state change is not allowed now; the message says why."""


class Supervisor:
    def __init__(self, rig: RigConfig, dt: float):
        self.rig = rig
        self.dt = dt
        self.state = State.STARTING
        self.cause = ""  # why the last trip happened
        self.events = EventLog()  # the loop's one event log (state changes, trips and all the rest)
        cfg = rig.safety
        self._n_bad = cfg.bad_samples_to_trip
        self._bad_sensor = 0
        self._bad_speed = 0
        self._limits = [j.limits for j in rig.joints]  # [rad or m]
        self._max_speed = [j.max_speed for j in rig.joints]  # [rad/s or m/s]
        self._p_max = rig.limits.max_pressure_mpa * 1e6
        self._dp = rig.limits.max_pressure_rate_mpa_s * 1e6 * dt  # per-cycle step limit [Pa]
        self.trips = 0
        self.enables = 0  # times the arm was enabled: tells one enabled period from the next
        self.recovery: Recovery | None = None  # joints enabled outside their limits, on their way back

    # -- state changes --------------------------------------------------------------------
    def _enter(self, state: State, cause: str = "") -> None:
        previous = self.state
        self.state = state
        self.events.add({"kind": "state", "from": previous.value, "to": state.value, "cause": cause})

    def started(self) -> None:
        if self.state is State.STARTING:
            self._enter(State.IDLE, "started")

    def trip(self, cause: str) -> bool:
        """Go to FAULT (unless already latched) with ``cause``; True if this was a new trip."""
        if self.state in (State.FAULT, State.ESTOP):
            return False
        self.recovery = None
        self.cause = cause
        self.trips += 1
        self.events.add({"kind": "trip", "cause": cause})
        self._enter(State.FAULT, cause)
        return True

    def estop(self, who: str = "") -> None:
        if self.state is not State.ESTOP:
            self.cause = f"e-stop{' from ' + who if who else ''}"
            self.events.add({"kind": "estop", "cause": self.cause})
            self._enter(State.ESTOP, self.cause)

    def enable(self, angles=None) -> Recovery | None:
        """IDLE -> ENABLED with the joints at ``angles`` [rad]; a joint outside its limits
        there is allowed on its way back (:mod:`daemon.loop.recovery`): the recovery, or None."""
        if self.state is not State.IDLE:
            raise StateError(f"cannot enable from {self.state.value}"
                             + (f" ({self.cause}); reset first" if self.state in (State.FAULT, State.ESTOP) else ""))
        self._bad_sensor = self._bad_speed = 0
        self.enables += 1
        recovery = None if angles is None else Recovery([j.name for j in self.rig.joints], self._limits, angles,
                                                        self.dt, [j.position_unit for j in self.rig.joints])
        self.recovery = recovery if recovery is not None and not recovery.finished else None
        self._enter(State.ENABLED, "enabled")
        if self.recovery is not None:
            self.events.add({"kind": "recover", "action": "start", **self.recovery.summary,
                             "cause": "enabled with joints outside their limits: moving them back inside"})
        return self.recovery

    def disable(self) -> None:
        if self.state is State.ENABLED:
            self.recovery = None
            self._enter(State.IDLE, "disabled")

    def reset(self, current_faults: tuple[str, ...]) -> None:
        """Leave FAULT/ESTOP for IDLE, refused while a sensor still reads implausibly."""
        if self.state not in (State.FAULT, State.ESTOP):
            raise StateError(f"nothing to reset: state is {self.state.value}")
        if current_faults:
            raise StateError(f"cannot reset while {current_faults[0]}")
        self._bad_sensor = self._bad_speed = 0
        self.cause = ""
        self._enter(State.IDLE, "reset")

    @property
    def enabled(self) -> bool:
        return self.state is State.ENABLED

    # -- per-cycle checks -----------------------------------------------------------------
    def check(self, angles, velocities, faults: tuple[str, ...], sample_age: float) -> None:
        """Trip on implausible sensors, stale input, joint limits or speed (checked every cycle)."""
        if faults:
            self._bad_sensor += 1
            if self._bad_sensor >= self._n_bad:
                self.trip(f"{faults[0]} ({self._bad_sensor} samples in a row)")
            return
        self._bad_sensor = 0
        if sample_age > self.rig.safety.stale_after_s:
            self.trip(f"transport data is stale: last sample {sample_age * 1e3:.1f} ms old "
                      f"(limit {self.rig.safety.stale_after_s * 1e3:.1f} ms: the rig file's [safety] stale_after_s, "
                      f"or pneumad --safety stale_after_s=...; 'pneumad latency' measures what this PC keeps)")
            return
        if self.state is not State.ENABLED:
            return
        limits = self._limits
        if self.recovery is not None:  # joints enabled outside their limits: their own rule until back
            limits = self._recovering(angles)
            if limits is None:
                return
        for joint, q, (lo, hi) in zip(self.rig.joints, angles, limits):
            if not lo <= q <= hi:
                self.trip(f"joint {joint.name} at {joint.shown(q)} is outside its limits {joint.shown_limits()}")
                return
        for fast, (w, limit) in enumerate(zip(velocities, self._max_speed)):
            if abs(w) > limit:
                break
        else:
            self._bad_speed = 0
            return
        self._bad_speed += 1
        if self._bad_speed >= self._n_bad:
            joint = self.rig.joints[fast]
            self.trip(f"joint {joint.name} moving at {joint.shown(velocities[fast], True)}, "
                      f"over its {joint.shown(joint.max_speed, True)} limit")

    def _recovering(self, angles) -> list | None:
        """One cycle of the recovery: the limits the usual rule checks now (none for the joints
        still on their way back), or None after a trip (further out, or not back in time)."""
        recovery = self.recovery
        cause = recovery.check(angles)
        if cause is not None:
            self.trip(cause)
            return None
        if recovery.finished:
            self.recovery = None
            self.events.add({"kind": "recover", "action": "done", "after_s": recovery.cycles * self.dt,
                             "cause": "every joint back inside its limits"})
        return recovery.limits

    def clamp(self, pressures: list[float], previous: list[float]) -> list[float]:
        """Limit each chamber command [Pa] to the rig's maximum and its slew rate."""
        p_max, dp = self._p_max, self._dp
        out = []
        for p, last in zip(pressures, previous):  # hal.bounds.clip, inline: this runs every cycle
            p = p if p < p_max else p_max
            out.append(last - dp if p < last - dp else last + dp if p > last + dp else p)
        return out
