"""The fixed-rate control loop: one cycle = read -> check -> control -> clamp -> write ->
telemetry -> commands, on absolute deadlines (no drift).

Everything here runs in one thread and does bounded work. Commands are handled at the end
of a cycle, so whatever they change takes effect at the next cycle boundary. An overrun is
counted and the loop skips ahead to the next deadline, holding the last command; it never
bursts to catch up. The clock is injectable: on a virtual clock the same loop runs in
lockstep with the simulator.
"""
from __future__ import annotations

import copy
import math

from controllers.base import (
    Controller,
    JointState,
    Reference,
    check_output,
)
from controllers.hold import Hold
from controllers.trajectory import Hold as HoldPosition
from controllers.trajectory import Trajectory
from daemon.loop.open_loop import OpenLoopRun
from daemon.loop.parts import LoopParts
from daemon.loop.safety import State, StateError
from daemon.loop.shadow import ShadowRun
from daemon.loop.stats import LoopStats
from daemon.loop.view import LoopView
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed
from hal.errors import CommandError, TransportError
from hal.rig import RigIO, Snapshot

START_WAIT_S = 1.0  # how long start() waits for a fresh first sample [s]

class ControlLoop:
    def __init__(self, io: RigIO, clock, parts: LoopParts, telemetry=None, server=None, contact_sensor=None):
        """The loop over ``io`` on ``clock``, from ``parts`` built beforehand (:mod:`daemon.assembly`)."""
        self.io = io
        self.rig = io.config
        self.clock = clock
        self.period = parts.context.dt
        self.n = len(io.joint_names)
        self.actuation = parts.actuation  # the joints' command interfaces
        self.context = parts.context
        self.supervisor = parts.supervisor
        self.events = parts.supervisor.events  # the one event log (daemon.loop.events), drained each cycle
        self.controller_plugins = parts.controller_plugins  # name -> module:Class, from the daemon's configuration
        self.controller: Controller = parts.controller
        self.shadow_run: ShadowRun | None = None  # a candidate run beside the active controller
        self.tracking = parts.tracking
        # built before the loop runs, and copied when needed: a fallback never builds in a cycle
        self._fallback = parts.fallback
        self.telemetry = telemetry
        self.server = server
        self.contact_sensor = contact_sensor  # daemon.contact.process: the latest contact estimate, or None
        self.stats = LoopStats()
        self.cycle = 0
        self.stop_requested = False
        self.trajectory: Trajectory = HoldPosition([0.0] * self.n)
        self.trajectory_name = "hold"
        self.trajectory_t0 = 0.0
        self.trajectory_generation = 0  # counts every change of reference: a plan made before one is stale
        self._reference_running = False  # a timed reference whose end event is still to come
        self.open_loop: OpenLoopRun | None = None  # an input-side experiment in progress
        self.u = list(self.actuation.neutral)  # last commands applied (V_MV [V] per cylinder joint: the
        #                                        controller's plus a known load's feed-forward; a muscle pair's [Pa])
        self.feed_forward = parts.feed_forward
        self.p_head, self.p_rod = list(io.safe_pressures[0]), list(io.safe_pressures[1])
        self.reference = ([0.0] * self.n, [0.0] * self.n, [0.0] * self.n)
        self.stiffness = [math.nan] * self.n  # stiffness set-point per joint [N m/rad]; NaN: the controller's own
        self.pressures: tuple[float, ...] = ()  # measured chamber pairs [Pa] (joints with sensors)
        self.angles = [0.0] * self.n  # last valid angles [rad]
        self.velocities = [0.0] * self.n  # filtered [rad/s]
        self.force = math.nan
        self.snapshot: Snapshot | None = None
        self._filter_w = 2 * math.pi * self.rig.safety.velocity_filter_hz  # velocity low-pass [rad/s]
        self.stats_period = 1.0  # [s] window of the 'stats' telemetry
        self._deadline = 0.0
        self._stats_due = 0.0
        self.heartbeat = None  # called every heartbeat_interval with the loop (e.g. the systemd watchdog)
        self.heartbeat_interval = 1.0
        self._heartbeat_due = 0.0
        self.view = LoopView(self)  # what status and describe read

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> None:
        """Write the safe state, take a first reading, and go IDLE; the first deadline is one
        period from now, so call :meth:`run` straight after."""
        self._write_safe()
        try:
            snap = self._first_reading()
            self.angles = [a if a == a else 0.0 for a in snap.angles]
            self.snapshot = snap
        except TransportError as exc:
            self.supervisor.trip(f"transport: {exc}")
        self.hold()
        self.supervisor.started()
        self._deadline = self.clock.now() + self.period
        self._stats_due = self._deadline + self.stats_period
        self._heartbeat_due = self._deadline
        self._drain_events()

    def _first_reading(self) -> Snapshot:
        """A sample no older than the stale limit. A transport across a wire answers the
        safe outputs just written a moment later, and its last sample may date from when it
        was opened, before the daemon's set-up: wait for a fresh one, a period at a time,
        for at most START_WAIT_S (this is start-up, not a cycle). The safe outputs are written
        again each period: a sample is as old as the request it answers, so a bridge that
        answered the first request late (busy at power-up, or on a loaded host) would
        otherwise never give one fresh enough."""
        limit, clock = self.rig.safety.stale_after_s, self.clock
        give_up = clock.now() + START_WAIT_S
        while True:
            snap = self.io.read()
            now = clock.now()
            if now - snap.t <= limit:
                return snap
            if now >= give_up:
                raise TransportError(f"no fresh sample within {START_WAIT_S:g} s of start "
                                     f"(the last is {(now - snap.t) * 1e3:.0f} ms old)")
            clock.sleep_until(now + self.period)
            self._write_safe()

    def run(self, cycles: int | None = None) -> None:
        """Run until :meth:`stop` (or for ``cycles`` cycles); :meth:`shutdown` leaves the outputs safe."""
        done = 0
        clock, period, stats = self.clock, self.period, self.stats
        stall_limit = self.rig.safety.stall_after_s
        while not self.stop_requested and (cycles is None or done < cycles):
            clock.sleep_until(self._deadline)
            wake = clock.now()
            lateness = wake - self._deadline
            stats.latency.add(lateness)
            if lateness > stall_limit:
                self.supervisor.trip(f"loop stalled: woke {lateness * 1e3:.1f} ms late "
                                     f"(limit {stall_limit * 1e3:.1f} ms)")
            self._cycle(wake)
            done += 1
            self._deadline += period
            end = clock.now()
            if end - wake > stall_limit:  # a cycle that ran this long held the outputs: trip and write safe now
                self.supervisor.trip(f"loop stalled: a cycle ran {(end - wake) * 1e3:.1f} ms "
                                     f"(limit {stall_limit * 1e3:.1f} ms)")
                self._write_safe()
                self._drain_events()
            if end > self._deadline:  # overrun: skip the deadlines already missed, hold the output
                missed = int((end - self._deadline) / period) + 1
                self._deadline += missed * period
                stats.overruns += missed
                stats.overruns_total += missed

    def stop(self) -> None:
        self.stop_requested = True

    def shutdown(self, reason: str = "shutdown") -> None:
        """Safe outputs, then close the transport (on SIGTERM, SIGINT, or any exit)."""
        self.events.add({"kind": "shutdown", "cause": reason})
        self._write_safe()
        self._drain_events()
        self.io.transport.close()
        if self.contact_sensor is not None:
            self.contact_sensor.close()

    # -- one cycle ------------------------------------------------------------------------
    def _cycle(self, wake: float) -> None:
        clock, sup = self.clock, self.supervisor
        t0 = clock.now()
        try:
            snap = self.io.read()
        except TransportError as exc:
            snap = None
            sup.trip(f"transport read failed: {exc}")
        t1 = clock.now()
        if snap is not None:
            self._update_measurement(snap)
            # the sample's age at this cycle's deadline: how late the transport is, not the
            # loop (its own lateness is the stall check's, and the wake-up latency figures')
            sup.check(snap.angles, self.velocities, snap.faults, self._deadline - snap.t)
        if sup.enabled:
            self._control(wake)
        t2 = clock.now()
        if sup.enabled:
            self._write_command()
        else:
            self._write_safe()
        t3 = clock.now()
        self.cycle += 1
        self.stats.cycles += 1
        self.stats.cycles_total += 1
        if self.telemetry is not None:
            self.telemetry.record(self)
        self._drain_events()
        if wake >= self._stats_due - 0.5 * self.period:  # half a period absorbs float rounding
            self._stats_due += self.stats_period
            window = self.stats.close_window(wake, self.period)
            if window is not None and self.telemetry is not None:
                self.telemetry.stats(window)
        t4 = clock.now()
        if self.server is not None:
            self.server.poll(self)
        if self.heartbeat is not None and wake >= self._heartbeat_due:
            self._heartbeat_due += self.heartbeat_interval
            self.heartbeat(self)
        self.stats.record_cycle(t0, t1, t2, t3, t4, clock.now())

    def _update_measurement(self, snap: Snapshot) -> None:
        """Keep the last valid angle per joint (one bad sample is not yet a fault) and a
        low-pass filtered velocity [rad/s]. The angle is differenced over the time between
        the two samples, not over a period: after a stall (the loop's or the transport's) the
        arm has moved for all of it, and dividing that by 1 ms would read as a speed trip."""
        previous, self.snapshot = self.snapshot, snap
        dt = snap.t - previous.t if previous is not None else self.period
        if dt > 0.0:
            a, inv_dt = -math.expm1(-self._filter_w * dt), 1.0 / dt
            for i, q in enumerate(snap.angles):
                if q == q:
                    raw = (q - self.angles[i]) * inv_dt
                    self.velocities[i] += a * (raw - self.velocities[i])
                    self.angles[i] = q
        self.force = snap.force
        self.pressures = snap.pressures

    def _control(self, now: float) -> None:
        if self._reference_running and now - self.trajectory_t0 >= self.trajectory.duration:
            self._end_reference()
        ref = self.trajectory.sample(now - self.trajectory_t0)
        self.reference = ref
        state = JointState(now, self.angles, self.velocities, self.pressures)
        reference = Reference(*ref, self.stiffness)
        ff = self.feed_forward
        if ff.load is not None:
            ff.update(self.controller, ref[0])
        try:
            u = self.controller.step(state, reference)
            check_output(u, self.actuation.width)
        except Exception as exc:  # a plugin's failure must never take the loop down
            self.replace_failed_controller(f"controller {self.controller.name} failed: {type(exc).__name__}: {exc}")
            return
        self.u = ff.added(u) if ff.load is not None else list(u)  # the loop's own copy: a plugin may reuse its buffer
        judged = ref[0]
        if self.open_loop is not None:
            if self.open_loop.apply(self, now):
                judged = self.open_loop.tracking_reference(ref[0], self.angles)
            else:
                self._end_open_loop()
        lost = self.tracking.check(now, judged, self.angles)
        if lost is not None:
            self.controller_lost(lost)
        if self.shadow_run is not None:
            try:
                self.shadow_run.step(state, reference, self.feed_forward.share(self.u))
            except Exception as exc:  # the candidate's failure ends its run, nothing more
                self._end_shadow("failed", f"{type(exc).__name__}: {exc}")

    def replace_failed_controller(self, cause: str) -> None:
        """Trip to the safe state and put the hold controller in the failed one's place."""
        failed = self.controller.name
        self.supervisor.trip(cause)
        hold = Hold(self.context)
        hold.reset(self._state(), self.feed_forward.share(self.u))
        self.controller = hold
        self.events.add({"kind": "controller", "from": failed, "to": "hold", "cause": cause,
                         "params": hold.get_params()})

    def controller_lost(self, cause: str) -> None:
        """The tracking rule fired: the fallback controller takes over and holds the arm where
        it is, or (no fallback configured, or the fallback itself lost the joint) a trip."""
        lost, spare = self.controller.name, self._fallback
        if spare is not None and lost != spare.name:
            self.events.add({"kind": "tracking", "controller": lost, "cause": cause,
                             "action": "fallback", "to": spare.name})
            self.switch(copy.deepcopy(spare), f"fallback: {lost}: {cause}")
            self.hold()
            return
        self.events.add({"kind": "tracking", "controller": lost, "cause": cause, "action": "trip"})
        self.supervisor.trip(f"controller {lost}: {cause}")

    def _write_command(self) -> None:
        p_head, p_rod, brakes = self.actuation.outputs(self.u)
        clamp = self.supervisor.clamp
        p_head, p_rod = clamp(p_head, self.p_head), clamp(p_rod, self.p_rod)
        try:
            self.io.write_pressures(p_head, p_rod, brakes)
        except (TransportError, CommandError) as exc:
            self.supervisor.trip(f"output write failed: {exc}")
            self._write_safe()
            return
        self.p_head, self.p_rod = p_head, p_rod

    def _write_safe(self) -> None:
        try:
            self.io.write_safe()
        except TransportError as exc:
            self.supervisor.trip(f"cannot write the safe state: {exc}")  # retried every cycle
        self.p_head, self.p_rod = list(self.io.safe_pressures[0]), list(self.io.safe_pressures[1])

    def _drain_events(self) -> None:
        if self.events.pending:
            self.events.drain(self._publish_event if self.telemetry is not None else None)

    def _publish_event(self, event: dict) -> None:
        self.telemetry.event(self, event)

    # -- the controls: the only ways a command changes the loop, each taking effect at a --
    # -- cycle boundary (handlers call them at the end of a cycle; estop acts at once)    --
    def enable(self) -> None:
        """IDLE -> ENABLED, the controllers reset from the state now, holding where the arm is."""
        self.supervisor.enable()
        self.u = list(self.actuation.neutral)
        state = self._state()
        self.controller.reset(state, self.u)
        if self.shadow_run is not None:
            self.shadow_run.controller.reset(state, self.u)
        self.hold()

    def disable(self) -> None:
        self.supervisor.disable()

    def estop(self, who: str = "") -> None:
        """Latch the e-stop and write the safe outputs now, in this very cycle."""
        self.supervisor.estop(who)
        self._write_safe()
        self._drain_events()

    def reset(self) -> None:
        faults = self.snapshot.faults if self.snapshot is not None else ("no reading yet",)
        self.supervisor.reset(faults)

    def hold(self) -> None:
        """Hold the present position (an abort): any reference running ends ``cut``."""
        self.set_trajectory(HoldPosition(self.angles), "hold")

    def require_enabled(self) -> None:
        """Refuse (``bad_state``, reason ``state``) unless the arm is enabled."""
        if not self.supervisor.enabled:
            raise CommandFailed(P.BAD_STATE, f"the arm is {self.state.value}: enable it first",
                                {"reason": "state", "state": self.state.value})

    def install(self, plan) -> None:
        """Install a planner's plan (daemon.planner.plans.Plan), unless it was overtaken: made
        against another reference generation or set-point (an abort, e-stop, another reference),
        refused ``bad_state`` reason ``overtaken``; or the arm is no longer enabled."""
        if plan.generation != self.trajectory_generation or list(self.reference[0]) != list(plan.start):
            raise CommandFailed(P.BAD_STATE, "the reference changed while this was planned (an abort, a reset, "
                                             "another command): nothing was started", {"reason": "overtaken"})
        self.require_enabled()
        self.set_trajectory(plan.trajectory, plan.name, plan.record, plan.stiffness)

    def set_load(self, load) -> None:
        """Feed ``load`` (controllers.known_load, or None) forward from the next cycle."""
        self.feed_forward.change(load, self.controller, self.reference[0])
        if self.supervisor.enabled:  # bumplessly: the applied sum does not jump
            self.controller.reset(self._state(),
                                  self.feed_forward.share(self.u))
        self.events.add({"kind": "load", "action": "set" if load else "clear",
                         **(load.describe() if load else {})})

    def switch(self, new: Controller, cause: str = "switch") -> None:
        """Swap in a controller built and validated beforehand; bumpless via reset()."""
        new.reset(self._state(), self.feed_forward.share(self.u))
        old = self.controller.name
        self.controller = new
        self.tracking.clear()
        self.events.add({"kind": "controller", "from": old, "to": new.name, "cause": cause,
                         "params": new.get_params()})

    def set_params(self, controller: Controller, prepared) -> dict:
        """Apply a parameter change prepared for ``controller``; refused (``refused``, reason
        ``overtaken``) if another controller became active meanwhile. The parameters now."""
        if self.controller is not controller:
            raise CommandFailed(P.REFUSED, f"the controller changed to {self.controller.name} while the change for "
                                           f"{controller.name} was prepared; nothing was applied",
                                {"reason": "overtaken"})
        controller.apply_params(prepared)
        params = controller.get_params()
        self.events.add({"kind": "params", "controller": controller.name, "params": params})
        return params

    def shadow(self, candidate: Controller) -> None:
        """Run ``candidate`` beside the active controller from the next cycle (replacing any
        shadow run already going); it starts from the present state and output."""
        if self.shadow_run is not None:
            self._end_shadow("replaced", f"by {candidate.name}")
        candidate.reset(self._state(), self.feed_forward.share(self.u))
        self.shadow_run = ShadowRun(candidate, self.actuation.width)
        self.events.add({"kind": "shadow", "action": "start", "controller": candidate.name})

    def commit(self) -> dict:
        """Make the shadow candidate the active controller, bumplessly (reset from the measured
        state and the output in force, as any switch); the run's comparison."""
        if self.shadow_run is None:
            raise StateError("no shadow run to commit: start one with controller.shadow")
        candidate = self.shadow_run.controller
        summary = self._end_shadow("commit")
        self.switch(candidate, "shadow commit")
        return summary

    def discard(self) -> dict:
        """End the shadow run without applying it; the run's comparison."""
        if self.shadow_run is None:
            raise StateError("no shadow run to discard")
        return self._end_shadow("discard")

    # -- what the controls are built on ---------------------------------------------------
    def set_trajectory(self, trajectory: Trajectory, name: str, record: str | None = None,
                       stiffness: list[float] | None = None) -> None:
        """Install a reference from the next cycle on (with a new stiffness set-point [N m/rad]
        per joint, NaN: the controller's own, where ``stiffness`` is given). One that runs for a
        time has ``reference`` events at its start and end (a recording bound to it, ``record``,
        follows them); one replaced before its end ends ``cut``."""
        if stiffness is not None:
            self.stiffness = list(stiffness)
        if self._reference_running:
            self._end_reference(cut=f"replaced by {name}")
        if self.open_loop is not None:
            self.open_loop.ended = ""
            self._end_open_loop()
        self.trajectory, self.trajectory_name = trajectory, name
        self.trajectory_generation += 1
        self.trajectory_t0 = self.clock.now() + self.period  # sampled from the next cycle on
        self.reference = trajectory.sample(0.0)
        self.tracking.clear()
        self._reference_running = trajectory.duration > 0.0 or record is not None  # a recorded step: its response
        if getattr(trajectory, "open_loop", False):
            self.open_loop = OpenLoopRun(trajectory, self.trajectory_t0, self.io.joint_names[trajectory.joint])
        if self._reference_running:
            self.events.add({"kind": "reference", "action": "start", "name": name,
                             "generation": self.trajectory_generation,
                             "duration_s": trajectory.duration, "record": record,
                             "signal": getattr(trajectory, "definition", None)})

    def reference_remaining(self) -> float:
        """How long the present reference runs on [s] (0 once it has ended, or for a hold)."""
        if self.trajectory.duration <= 0.0:
            return 0.0
        return max(self.trajectory.duration - (self.clock.now() - self.trajectory_t0), 0.0)

    def _end_open_loop(self) -> None:
        """Feedback takes the excited joint back, bumplessly from the output in force; an
        experiment that left its band is cut, the arm held where it is."""
        run, self.open_loop = self.open_loop, None
        self.controller.reset(self._state(), self.feed_forward.share(self.u))
        if run.ended and run.ended != "done":
            self.events.add({"kind": "experiment", "action": "abort", "joint": run.name, "cause": run.ended})
            self.hold()

    def _end_reference(self, cut: str = "") -> None:
        self._reference_running = False
        self.events.add({"kind": "reference", "action": "end", "name": self.trajectory_name,
                         "generation": self.trajectory_generation, "cut": cut})

    def _end_shadow(self, action: str, cause: str = "") -> dict:
        """Stop the shadow run; its summary (also published as an event)."""
        summary = self.shadow_run.summary()
        self.shadow_run = None
        self.events.add({"kind": "shadow", "action": action, "cause": cause, **summary})
        return summary

    def _state(self) -> JointState:
        """The measured state now, for a controller's reset."""
        return JointState(self.clock.now(), self.angles, self.velocities, self.pressures)

    @property
    def state(self) -> State:
        return self.supervisor.state

    @property
    def healthy(self) -> bool:
        """Cycling on time: fewer than 10 % of this window's cycles overran."""
        return self.stats.overruns * 10 <= max(self.stats.cycles, 1)
