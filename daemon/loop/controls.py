"""The loop's named controls: the only ways a command changes what the loop does (enable,
disable, estop, trip, reset, hold, install, set_load, switch, set_params, shadow, commit, discard),
each taking effect at a cycle boundary: the handlers call them at the end of a cycle; estop
writes the safe outputs at once. The loop's own turns (a failed controller replaced, a
fallback taking over for a controller that lost a joint or overran its step budget, an
experiment's end) go through them too.

A base of :class:`daemon.loop.cycle.ControlLoop`, whose state they change: kept apart from the
cycle so that each reads as one thing (ros2_control's explicit switch semantics).
"""
from __future__ import annotations

import copy
import time

from controllers.base import Controller
from controllers.directory import provenance
from controllers.hold import Hold
from controllers.trajectory import Hold as HoldPosition
from controllers.trajectory import JointMove, Trajectory
from daemon.loop.open_loop import OpenLoopRun
from daemon.loop.safety import StateError
from daemon.loop.settle import SettleGate
from daemon.loop.shadow import ShadowRun
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed

SHADOW_COMMIT_RMS = 0.5  # a shadow run's RMS difference, as a fraction of a command's range, a commit needs force past


class LoopControls:
    def replace_failed_controller(self, cause: str) -> None:
        """Trip to the safe state and put the hold controller in the failed one's place."""
        failed = self.controller.name
        self.supervisor.trip(cause)
        hold = Hold(self.context)
        hold.reset(self._state(), self.feed_forward.share(self.u))
        self.controller = hold
        self.events.add({"kind": "controller", "from": failed, "to": "hold", "cause": cause,
                         "params": hold.get_params()})

    def fall_back(self, cause: str) -> str:
        """Put the rig file's fallback controller in the active one's place (``hold``, which
        repeats the output in force, where the fallback is the one replaced or none is built) and
        hold the arm where it is: the ``[timing] policy = "hold"`` for a controller whose step is
        over its budget. The name of the controller now active."""
        slow, spare = self.controller.name, self._fallback
        new = copy.deepcopy(spare) if spare is not None and spare.name != slow else Hold(self.context)
        self.switch(new, f"fallback: {slow}: {cause}")
        self.hold()
        return new.name

    def controller_lost(self, cause: str) -> None:
        """The tracking rule fired: the fallback controller takes over and holds the arm where
        it is, or (no fallback configured, or the fallback itself lost the joint) a trip."""
        lost, spare = self.controller.name, self._fallback
        if self.rig.safety.tracking_action == "fallback" and spare is not None and lost != spare.name:
            self.events.add({"kind": "tracking", "controller": lost, "cause": cause,
                             "action": "fallback", "to": spare.name})
            self.switch(copy.deepcopy(spare), f"fallback: {lost}: {cause}")
            self.hold()
            return
        self.events.add({"kind": "tracking", "controller": lost, "cause": cause, "action": "trip"})
        self.supervisor.trip(f"controller {lost}: {cause}")

    def take_held(self) -> None:
        """The cycle watchdog wrote the safe state (:mod:`daemon.loop.watchdog`); at this cycle
        boundary: an e-stop the loop had not taken latches, a controller whose step it found
        still running is replaced as a failed one (a trip, ``hold`` in its place), another stall
        trips; then let go."""
        held = self.held
        held.done.wait(held.patience_s)  # its write made (the loop makes no transport call till then)
        self.held = None
        kind, cause, stepping = held.kind, held.cause, held.stepping
        if kind == "estop":
            self.supervisor.estop("the control socket (written safe by the cycle watchdog)")
        if stepping is not None and stepping == self.controller.name:
            self.replace_failed_controller(f"controller {stepping}'s step hung: {cause}")
        elif kind == "stall":
            self.supervisor.trip(f"loop stalled: {cause}")
        self._write_safe()
        self._drain_events()

    def enable(self) -> None:
        """IDLE -> ENABLED, the controllers reset from the state now, holding where the arm is;
        a joint outside its limits is moved back inside first (:mod:`daemon.loop.recovery`)."""
        recovery = self.supervisor.enable(self.angles)
        self.u = list(self.actuation.neutral)
        state = self._state()
        self.controller.reset(state, self.u)
        if self.shadow_run is not None:
            self.shadow_run.controller.reset(state, self.u)
        if recovery is None:
            self.hold()
        else:
            self.set_trajectory(JointMove(list(self.angles), recovery.targets, recovery.move_s), "recover")

    def disable(self) -> None:
        self.supervisor.disable()

    def estop(self, who: str = "") -> None:
        """Latch the e-stop (a request's) and write the safe outputs now, in this very cycle."""
        self.estop_taken_at = time.monotonic()  # the cycle watchdog's: this e-stop is taken
        self.supervisor.estop(who)
        self._write_safe()
        self._drain_events()

    def trip(self, cause: str) -> None:
        """Trip to the safe state (written from the next cycle) with ``cause`` (e.g. a lapsed lease)."""
        self.supervisor.trip(cause)

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
                         "params": new.get_params(), "source": provenance(type(new))})

    def set_params(self, controller: Controller, prepared) -> dict:
        """Apply a parameter change prepared for ``controller``; refused (``refused``, reason
        ``overtaken``) if another controller became active meanwhile. The parameters now."""
        if self.controller is not controller:
            raise CommandFailed(P.REFUSED, f"the controller changed to {self.controller.name} while the change for "
                                           f"{controller.name} was prepared; nothing was applied",
                                {"reason": "overtaken"})
        controller.apply_params(prepared)
        params = controller.get_params()
        self.events.add({"kind": "params", "controller": controller.name, "params": params,
                         "source": provenance(type(controller))})
        return params

    def shadow(self, candidate: Controller) -> None:
        """Run ``candidate`` beside the active controller from the next cycle (replacing any
        shadow run already going); it starts from the present state and output."""
        if self.shadow_run is not None:
            self._end_shadow("replaced", f"by {candidate.name}")
        candidate.reset(self._state(), self.feed_forward.share(self.u))
        self.shadow_run = ShadowRun(candidate, self.actuation.width)
        self.events.add({"kind": "shadow", "action": "start", "controller": candidate.name})

    def commit(self, force: bool = False) -> dict:
        """Make the shadow candidate the active controller, bumplessly (reset from the measured
        state and the output in force, as any switch); the run's comparison. A candidate whose
        output was, RMS over the run, more than ``SHADOW_COMMIT_RMS`` of a command's range away
        from the active controller's is refused unless ``force``: the comparison is what a shadow
        run is for, and a commit through one that large (a sign, a unit, a design for another
        plant) must not go without a word. Candidates of another kind differ too (SMC+DOB from
        PID by 3.2-4.2 V RMS of V_MV's 10 V on the README's paths, 6.2 V once along the
        translation where PID saturates; its largest difference is a start-up transient), which
        is why the bar is half the range, on the RMS."""
        if self.shadow_run is None:
            raise StateError("no shadow run to commit: start one with controller.shadow")
        if not force:
            self._check_shadow_agrees(self.shadow_run.summary())
        candidate = self.shadow_run.controller
        summary = self._end_shadow("commit")
        self.switch(candidate, "shadow commit")
        return summary

    def _check_shadow_agrees(self, summary: dict) -> None:
        """``refused`` (reason ``shadow_difference``) where the run's RMS difference on some
        command exceeds its share of that command's range."""
        for command, largest, rms in zip(self.actuation.commands, summary["max_diff_volts"], summary["rms_diff_volts"]):
            limit = SHADOW_COMMIT_RMS * (command.high - command.low)
            if rms > limit:
                raise CommandFailed(
                    P.REFUSED, f"{summary['controller']} would have commanded {rms:.3g} {command.unit} RMS away from "
                               f"{self.controller.name} on {command.joint}'s {command.name} (up to {largest:.3g} "
                               f"{command.unit}) over the shadow run, more than {SHADOW_COMMIT_RMS:.0%} of its range "
                               f"({limit:.3g} {command.unit}): a commit would change what the arm does; commit with "
                               f"force: true (pneumactl controller commit --force) if that is meant",
                    {"reason": "shadow_difference", "joint": command.joint, "command": command.name,
                     "max_diff": largest, "rms_diff": rms, "limit": limit, "unit": command.unit})

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
        approach = getattr(trajectory, "approach_s", None)  # a path after its approach: settle in between
        self._settle = None if approach is None else SettleGate(approach, trajectory.sample(approach)[0], self.period,
                                                                 self.io.position_units)
        if getattr(trajectory, "open_loop", False):
            self.open_loop = OpenLoopRun(trajectory, self.trajectory_t0, self.io.joint_names[trajectory.joint])
        if self._reference_running:
            self.events.add({"kind": "reference", "action": "start", "name": name,
                             "generation": self.trajectory_generation,
                             "duration_s": trajectory.duration, "record": record,
                             "signal": getattr(trajectory, "definition", None),
                             "approach_s": getattr(trajectory, "approach_s", None)})

    def _settle_or_start_path(self, now: float) -> None:
        """At and after the approach's end (``_settle``'s time): hold the path's start, the
        trajectory's clock stopped there, until the joints have settled on it or the wait is up;
        then the path runs from its first sample, with a ``reference`` event ``settled``."""
        gate = self._settle
        self.trajectory_t0 = now - gate.at
        if not gate.waiting(self.angles):
            self._settle = None
            self.events.add({"kind": "reference", "action": "settled", "name": self.trajectory_name,
                             "generation": self.trajectory_generation, **gate.summary(self.angles)})

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
