"""A trip pauses the plan instead of failing it: a Bluesky suspender on the daemon's state.

:class:`RigState` is the daemon's state (``enabled``, ``fault``, ``estop`` ...) as the signal a
Bluesky suspender watches: kept current from the ``event`` topic (a background subscription;
``status`` once at the start), and calling its subscribers at every change, as an ophyd
signal does. :func:`suspender` installs the rule a lab wants on a RunEngine: a trip or an e-stop
suspends the plan at once (the RunEngine rewinds it to its last checkpoint); the
plan hands the rig's lease back while suspended, so whoever resets the arm can take it
(``pneumactl reset``, ``pneumactl enable`` with their own key); once the arm is ``enabled``
again the plan takes the lease back and resumes from that checkpoint, its queue kept.
"""
from __future__ import annotations

import logging
import threading

from bluesky import plan_stubs as bps
from bluesky.suspenders import SuspenderBase

from daemon.client.client import RemoteError
from daemon.wire import protocol as P

log = logging.getLogger(__name__)

RESUME_SLEEP_S = 0.5  # after the arm is enabled again, this long before the plan goes on [s]


class RigState:
    """The daemon's state, as the signal a suspender watches (``subscribe``/``clear_sub``/``get``,
    the part of ophyd's signal interface bluesky's suspenders use)."""

    def __init__(self, link, name: str = "rig_state"):
        self.name = name
        self._link = link
        self._callbacks: list = []
        self._lock = threading.Lock()
        self._value = link.client.status()["state"]
        self._stop = threading.Event()
        self._subscription = link.client.subscribe((b"event",))
        self._feed = threading.Thread(target=self._follow, name=f"pneumad-{name}", daemon=True)
        self._feed.start()

    def get(self) -> str:
        return self._value

    def subscribe(self, callback, event_type=None, run: bool = True):
        with self._lock:
            self._callbacks.append(callback)
        if run:
            callback(value=self._value, old_value=None, obj=self)
        return callback

    def clear_sub(self, callback) -> None:
        with self._lock:
            if callback in self._callbacks:
                self._callbacks.remove(callback)

    def _follow(self) -> None:
        try:
            while not self._stop.is_set():
                received = self._subscription.receive(0.2)
                if received is None:
                    continue
                event = received[1]
                if event.get("kind") == "state" and event.get("to") != self._value:
                    old, self._value = self._value, event["to"]
                    log.info("%s: %s -> %s (%s)", self.name, old, self._value, event.get("cause", ""))
                    with self._lock:
                        callbacks = list(self._callbacks)
                    for callback in callbacks:
                        callback(value=self._value, old_value=old, obj=self)
        finally:
            self._subscription.close()

    def close(self) -> None:
        self._stop.set()
        self._feed.join(2.0)


def _hand_back(rig):
    """While suspended, the lease is the operator's to take (a plan that holds it would keep
    them from resetting the arm)."""
    def plan():
        client = rig.link.client
        if client.lease is not None:
            try:
                yield from bps.wait_for([lambda: rig.link.call("release_lease")])
            except RemoteError as exc:  # it lapsed, or the trip ended it: nothing to hand back
                if exc.code != P.NO_LEASE:
                    raise
    return plan


def _take_again(rig):
    """Before the plan goes on: the lease back, renewed in the background as at stage."""
    def plan():
        yield from bps.wait_for([rig.take_lease])
    return plan


TRIPPED = ("fault", "estop")  # the states a trip or an e-stop leaves the arm in


class SuspendOnTrip(SuspenderBase):
    """Suspends the plan when the arm trips or is e-stopped (not when it is idle: a plan's
    ``stage`` enables an idle arm), resumes it once the arm is ``enabled`` again."""

    def _should_suspend(self, value) -> bool:
        return value in TRIPPED

    def _should_resume(self, value) -> bool:
        return value == "enabled"

    def _get_justification(self) -> str:
        if not self.tripped:
            return ""
        return (f"{self._sig.name}: the arm is {self._sig.get()}: reset and enable it (pneumactl reset; "
                f"pneumactl enable) to resume the plan from its last checkpoint")


def suspender(rig, sleep: float = RESUME_SLEEP_S) -> SuspendOnTrip:
    """The suspender for ``rig`` (a :class:`~daemon.client.bluesky.device.PneumadRig`):
    ``RE.install_suspender(suspender(rig))``. It suspends the plan when the arm trips or is
    e-stopped, and resumes it ``sleep`` seconds after the arm is enabled again."""
    state = RigState(rig.link, name=f"{rig.name or rig.link.rig_name}_state")
    return SuspendOnTrip(state, sleep=sleep, pre_plan=_hand_back(rig), post_plan=_take_again(rig))
