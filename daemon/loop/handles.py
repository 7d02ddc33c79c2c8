"""What the loop's readers are given (status and describe through :class:`daemon.loop.view.LoopView`,
the lease, the command port, the timing verdicts): the loop's parts that never change once it is
built, its latest cycle record with its layout, and named
queries for the little that changes otherwise. No reader walks the loop's attributes; what a
handler changes, it changes through the loop's named controls (:mod:`daemon.loop.controls`)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from daemon.wire.cycle_layout import CycleLayout


class LoopQueries:
    """The named queries the loop gives its readers (a base of
    :class:`daemon.loop.cycle.ControlLoop`, whose state they read)."""

    def _cycles(self) -> int:
        return self.cycle

    def _latest(self) -> list[float]:
        return self.record

    def _active(self):
        return self.controller

    def _shadowing(self):
        return self.shadow_run

    def _reference_now(self) -> tuple[str, float]:
        return self.trajectory_name, self.reference_remaining()

    def _origin(self) -> tuple[int, list[float]]:
        return self.trajectory_generation, list(self.reference[0])

    def _faults(self) -> tuple[str, ...]:
        return self.snapshot.faults if self.snapshot is not None else ()

    def _stiffness(self) -> list[float]:
        return self.stiffness


@dataclass(frozen=True)
class LoopHandles:
    rig: object  # hal.config.RigConfig
    context: object  # the controllers' build context (controllers.base.ControllerContext)
    controller_plugins: dict[str, str]  # name -> module:Class, from the daemon's configuration
    period: float  # [s]
    command_interfaces: tuple  # hal.interfaces.CommandInterface, the controllers' output vector's
    transport: object  # hal.transport.Transport (its health, channels and helper process)
    clock: object  # the loop's clock (now)
    supervisor: object  # daemon.loop.safety.Supervisor: state, cause, trips, recovery
    events: object  # daemon.loop.events.EventLog: what a reader has to tell
    stats: object  # daemon.loop.stats.LoopStats: the overrun counts, the timing banks
    feed_forward: object  # daemon.loop.feed_forward.LoadFeedForward: a known load
    joint_outputs: tuple  # per joint, its output channels' names (head, rod[, brake]; a valve)
    contact_sensor: object | None  # daemon.contact.process.ContactSensor, or None
    layout: CycleLayout
    record: Callable[[], list[float]]  # the latest cycle's record (never changed once made)
    cycle: Callable[[], int]  # cycles run so far
    controller: Callable[[], object]  # the active controller (its name, parameters, internals)
    shadow: Callable[[], object | None]  # the shadow run (daemon.loop.shadow.ShadowRun), or None
    reference: Callable[[], tuple[str, float]]  # the reference's name, how long it runs on [s]
    origin: Callable[[], tuple[int, list[float]]]  # the reference generation and the set-point in force
    faults: Callable[[], tuple[str, ...]]  # the last reading's faults
    stiffness: Callable[[], list[float]]  # the stiffness set-point per joint [N m/rad]; NaN: the controller's
