"""The fixed-rate control loop: one cycle = read -> check -> control -> clamp -> write ->
telemetry -> commands, on absolute deadlines (no drift).

Everything here runs in one thread (the cycle watchdog beside it: :mod:`daemon.loop.watchdog`)
and does bounded work. Commands are handled at the end of a cycle, so whatever they change
takes effect at the next cycle boundary. An overrun is
counted and the loop skips ahead to the next deadline, holding the last command; it never
bursts to catch up. The clock is injectable: on a virtual clock the same loop runs in
lockstep with the simulator.
"""
from __future__ import annotations

import math
import types

from controllers.base import (
    Controller,
    JointState,
    Reference,
    check_output,
)
from controllers.trajectory import Hold as HoldPosition
from controllers.trajectory import Trajectory
from daemon.loop.controls import LoopControls
from daemon.loop.open_loop import OpenLoopRun
from daemon.loop.parts import LoopParts
from daemon.loop.record import RecordSpans, writer
from daemon.loop.safety import State
from daemon.loop.shadow import ShadowRun
from daemon.loop.stats import LoopStats
from daemon.loop.handles import LoopHandles, LoopQueries
from daemon.loop.view import LoopView
from daemon.loop.watchdog import Held
from daemon.wire.cycle_layout import MODE_INDEX, CycleLayout
from hal import sensors
from hal.errors import CommandError, TransportError
from hal.rig import RigIO, Snapshot


class ControlLoop(LoopControls, LoopQueries):
    def __init__(self, io: RigIO, clock, parts: LoopParts, layout: CycleLayout, telemetry=None, server=None,
                 contact_sensor=None, stats: LoopStats | None = None):
        """The loop over ``io`` on ``clock``, from ``parts`` built beforehand (:mod:`daemon.assembly`),
        recording each cycle on ``layout`` (the rig's declared interfaces'); its timing counted
        into ``stats`` (default: banks of its own, for a loop without a messenger)."""
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
        self.controller_dirs = parts.controller_dirs  # the controller directories' files, reloaded on request
        self.controller: Controller = parts.controller
        self.shadow_run: ShadowRun | None = None  # a candidate run beside the active controller
        self.tracking = parts.tracking
        # built before the loop runs, and copied when needed: a fallback never builds in a cycle
        self._fallback = parts.fallback
        self.telemetry = telemetry
        self.server = server
        self.contact_sensor = contact_sensor  # daemon.contact.process: the latest contact estimate, or None
        self.stats = stats if stats is not None else LoopStats()
        self.cycle = 0
        self.stop_requested = False
        self.trajectory: Trajectory = HoldPosition([0.0] * self.n)
        self.trajectory_name = "hold"
        self.trajectory_t0 = 0.0
        self.trajectory_generation = 0  # counts every change of reference: a plan made before one is stale
        self._reference_running = False  # a timed reference whose end event is still to come
        self._settle = None  # a path's wait at its start after the approach (daemon.loop.settle), until it runs
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
        self.snapshot: Snapshot | None = None
        self._filter_w = 2 * math.pi * self.rig.safety.velocity_filter_hz  # velocity low-pass [rad/s]
        self.stats_period = 1.0  # [s] window of the 'stats' telemetry
        self._deadline = 0.0  # the cycle in progress's deadline, or the next one's: the cycle watchdog reads it
        # The cycle watchdog's (daemon.loop.watchdog): in_io set around each transport call, made
        # only while held (its hold) is None; stepping names a step that hangs; an e-stop passed
        # after estop_taken_at is one the loop has not taken.
        self.in_io = False
        self.held: Held | None = None
        self.stepping: Controller | None = None
        self.estop_taken_at = 0.0  # when it last took an e-stop from the socket [s, time.monotonic]
        # When each cycle's write began [s] (a ring covering the stale limit): a pipelined wire
        # answers the request of the cycle before, so the transport is late by the time since
        # the first request it has not answered, not since the sample it gave (the loop's own
        # pauses in between are the stall rule's). See _input_age.
        size = 2 ** math.ceil(math.log2(self.rig.safety.stale_after_s / self.period + 2))
        self._writes, self._writes_mask, self._writes_n = [-math.inf] * size, size - 1, 0
        self._stale_limit = self.rig.safety.stale_after_s
        self._stats_due = 0.0
        self.heartbeat = None  # called every heartbeat_interval with the loop (e.g. the systemd watchdog)
        self.heartbeat_interval = 1.0
        self._heartbeat_due = 0.0
        # the cycle record: made at the end of each cycle (_record), read by telemetry and status
        self.layout = layout
        self.record = layout.record()
        self._mode_of, self._mode_index = None, 0.0  # the state whose index the record holds, and the index
        self._spans = RecordSpans.of(layout, list(io.joint_names), [f"{c.joint}.{c.name}" for c in self.actuation.commands],
                                     [i for i, d in enumerate(io.head) if d is not None],
                                     [f"{p.owner}.{p.name}" if p.owner else p.name for p in sensors.measured(self.rig)],
                                     [ch.name for ch in io.transport.outputs])
        # this cycle's record, at the end of each cycle: _record(snap), made for these spans
        self._record = types.MethodType(writer(self._spans, self.n, MODE_INDEX, State.ENABLED), self)
        self.handles = LoopHandles(
            self.rig, self.context, self.controller_plugins, self.period, self.actuation.commands, io.transport, clock,
            self.supervisor, self.events, self.stats, self.feed_forward, tuple(io.joint_outputs), contact_sensor, layout,
            self._latest, self._cycles, self._active, self._shadowing, self._reference_now, self._origin,
            self._faults, self._stiffness, self.controller_dirs, self._measured, self._output)
        self.view = LoopView(self.handles)  # what status and describe read

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
        self._record(self.snapshot)  # what status reads before the first cycle
        self._deadline = self.clock.now() + self.period
        self._stats_due = self._deadline + self.stats_period
        self._heartbeat_due = self._deadline
        self._drain_events()

    def _first_reading(self) -> Snapshot:
        """A sample no older than the stale limit. A transport across a wire answers the
        safe outputs just written a moment later, and its last sample may date from when it
        was opened, before the daemon's set-up: wait for a fresh one, a period at a time, for
        at most the transport's ``open_timeout_s`` (this is start-up, not a cycle). The safe
        outputs are written again each period: a sample is as old as the request it answers,
        so a bridge that answered the first request late (busy at power-up, or on a loaded
        host) would otherwise never give one fresh enough."""
        limit, clock = self.rig.safety.stale_after_s, self.clock
        wait_s = self.io.transport.open_timeout_s
        give_up = clock.now() + wait_s
        while True:
            snap = self.io.read()
            now = clock.now()
            if now - snap.t <= limit:
                return snap
            if now >= give_up:
                raise TransportError(f"no fresh sample within {wait_s:g} s of start (the last is "
                                     f"{(now - snap.t) * 1e3:.0f} ms old; a slow rig: transport option open_timeout_s)")
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
            if self.held is not None:  # the cycle watchdog wrote the safe state meanwhile
                self.take_held()
            done += 1
            deadline = self._deadline + period  # stored once, below: the watchdog never sees one already missed
            end = clock.now()
            if end - wake > stall_limit:  # a cycle that ran this long held the outputs: trip and write safe now
                self.supervisor.trip(f"loop stalled: a cycle ran {(end - wake) * 1e3:.1f} ms "
                                     f"(limit {stall_limit * 1e3:.1f} ms)")
                self._write_safe()
                self._drain_events()
            if end > deadline:  # overrun: skip the deadlines already missed, hold the output
                missed = int((end - deadline) / period) + 1
                deadline += missed * period
                stats.overruns += missed
                stats.overruns_total += missed
            self._deadline = deadline

    def run_at(self, deadline: float) -> None:
        """One cycle woken at ``deadline`` on the loop's clock, the deadlines before it skipped as
        an overrun skips them: a recorded cycle run again at its own time (daemon/replay), where
        the recording's loop did not keep its period."""
        self._deadline = max(self._deadline, deadline)
        self.run(1)

    def stop(self) -> None:
        self.stop_requested = True

    def shutdown(self, reason: str = "shutdown") -> None:
        """Safe outputs, then close the transport (on SIGTERM, SIGINT, or any exit)."""
        self.events.add({"kind": "shutdown", "cause": reason})
        self.held = None  # the watchdog is stopped by now (daemon.main): the loop's own write, whatever it did
        self._write_safe()
        self._drain_events()
        self.io.transport.close()
        if self.contact_sensor is not None:
            self.contact_sensor.close()

    # -- one cycle ------------------------------------------------------------------------
    def _cycle(self, wake: float) -> None:
        clock, sup = self.clock, self.supervisor
        t0 = clock.now()
        self.in_io = True
        try:
            snap = self.io.read() if self.held is None else None
        except TransportError as exc:
            snap = None
            sup.trip(f"transport read failed: {exc}")
        finally:
            self.in_io = False
        t1 = clock.now()
        if snap is not None:
            self._update_measurement(snap)
            # the sample's age at this cycle's deadline: how late the transport is, not the
            # loop (its own lateness and pauses are the stall check's, and the wake-up latency
            # figures')
            age = self._deadline - snap.t
            if age > self._stale_limit:
                age = self._input_age(snap.t)
            sup.check(snap.angles, self.velocities, snap.faults, age)
        if sup.enabled:
            self._control(wake)
        t2 = clock.now()
        self._writes[self._writes_n & self._writes_mask] = t2
        self._writes_n += 1
        if sup.enabled:
            self._write_command()
        else:
            self._write_safe()
        t3 = clock.now()
        self.cycle += 1
        self.stats.cycles += 1
        self.stats.cycles_total += 1
        self._record(snap)
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
            self.server.poll(self.cycle)
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
        self.pressures = snap.pressures

    def _input_age(self, sample_t: float) -> float:
        """How late the transport is at this cycle's deadline [s], for a sample dated
        ``sample_t`` that looks stale: counted from the first write after it (the first request
        the transport has not answered), so a pause of the loop's own between that sample's
        request and the next is left out; from the sample itself when no write came after it,
        and from the oldest write the ring holds when all came after (never an understatement
        within the stale limit: the ring covers it). Only in a cycle whose sample is older
        than the limit, so the search costs nothing in the others."""
        writes, mask, n = self._writes, self._writes_mask, self._writes_n
        oldest = max(n - len(writes), 0)
        i = n - 1
        while i >= oldest and writes[i & mask] > sample_t:
            i -= 1
        if i == n - 1:
            return self._deadline - sample_t
        return self._deadline - writes[(i + 1) & mask]

    def _control(self, now: float) -> None:
        if self._reference_running and now - self.trajectory_t0 >= self.trajectory.duration:
            self._end_reference()
        if self._settle is not None and now - self.trajectory_t0 >= self._settle.at:
            self._settle_or_start_path(now)
        ref = self.trajectory.sample(now - self.trajectory_t0)
        self.reference = ref
        state = JointState(now, self.angles, self.velocities, self.pressures)
        reference = Reference(*ref, self.stiffness)
        ff = self.feed_forward
        if ff.load is not None:
            ff.update(self.controller, ref[0])
        self.stepping = self.controller
        try:
            u = self.controller.step(state, reference)
            check_output(u, self.actuation.width)
        except Exception as exc:  # a plugin's failure must never take the loop down
            self.stepping = None
            self.replace_failed_controller(f"controller {self.controller.name} failed: {type(exc).__name__}: {exc}")
            return
        self.stepping = None
        if self.held is not None:  # the watchdog wrote the safe state while it ran: not this output
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

    def _write_command(self) -> None:
        p_head, p_rod, brakes = self.actuation.outputs(self.u)
        clamp = self.supervisor.clamp
        p_head, p_rod = clamp(p_head, self.p_head), clamp(p_rod, self.p_rod)
        self.in_io = True
        try:
            if self.held is None:  # else the watchdog's safe state stays
                self.io.write_pressures(p_head, p_rod, brakes)
                self.p_head, self.p_rod = p_head, p_rod
            return
        except (TransportError, CommandError) as exc:
            self.supervisor.trip(f"output write failed: {exc}")
        finally:
            self.in_io = False
        self._write_safe()

    def _write_safe(self) -> None:
        self.in_io = True
        try:
            if self.held is None:  # else the watchdog writes it
                self.io.write_safe()
        except TransportError as exc:
            self.supervisor.trip(f"cannot write the safe state: {exc}")  # retried every cycle
        finally:
            self.in_io = False
        self.p_head, self.p_rod = list(self.io.safe_pressures[0]), list(self.io.safe_pressures[1])

    def _drain_events(self) -> None:
        if self.events.pending:
            self.events.drain(self._publish_event if self.telemetry is not None else None)

    def _publish_event(self, event: dict) -> None:
        self.telemetry.event(self, event)

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
