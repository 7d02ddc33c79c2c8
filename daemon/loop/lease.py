"""The lease: which one client may move the arm, and what becomes of an arm nobody holds.

One controlling client holds the lease (a token) and must renew it within its time to live;
the lease is bound to the key that took it (:class:`daemon.wire.keys.Identity`), and an observer
key may not take it. A lease that lapses while the arm is enabled trips it: the client that
was in charge has gone. An arm left enabled by a client that handed the lease back runs its
reference to the end and holds; after the rig file's grace time of holding with no lease
holder it is disabled (``[safety] unleased_action = "disable"``, ``unleased_grace_s``), or
held until a client comes (``"hold"``). A key taken off the allow-list loses its lease at
once (:meth:`Lease.revoke`). Each change of holder is an event (``lease``: acquired, released,
lapsed; ``lease_revoked``), so the journal tells who held the arm when. Everything here runs on
the loop's thread, once a cycle or per request, in constant time.

Renewals come through the messenger process. A lease whose time runs out while the messenger
is down or restarting (its death seen, its successor not yet ready) is held over, and once
the new messenger is ready its holder has the lease's full ttl from then to renew (requests
it sent meanwhile wait in its socket, or were lost with the old messenger). A lease never
outlives its own time by more than ``HOLD_S``, however the messenger fares: a client that
really died during a restart loses its lease ttl after the new messenger was ready, at the
latest ``HOLD_S`` past its time.

The lease's clock stops while the loop does not cycle: a pause of the loop (a loaded PC holding a
loop without real-time scheduling off the CPU for a second or more) is not the holder's
silence. Its renewals wait in the rings meanwhile (or are refused by the messenger answering for
a stalled loop, and sent again), and the first cycle after the pause comes before the rings are
served; the pause (past ``PAUSE_S``) is added to the lease's time, so a client that renewed all
along keeps it. Jitter under ``PAUSE_S`` counts as time, so a dead client's lease is not
stretched by a loop that is merely late.
"""
from __future__ import annotations

import secrets
from collections.abc import Callable

from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed
from daemon.wire.keys import ANONYMOUS, OBSERVER, Identity

HOLD_S = 5.0  # a lease held over across a messenger restart: at most this long past its own time [s]
PAUSE_S = 0.1  # a gap between two cycles longer than this is a pause of the loop: not the lease's time [s]


class Lease:
    def __init__(self, handles, hold: Callable[[], None], disable: Callable[[], None]):
        """On the loop's ``handles`` (:mod:`daemon.loop.handles`: its clock, supervisor, events,
        the reference's time left), with its named controls ``hold`` and ``disable``."""
        self._clock, self._supervisor, self._events = handles.clock, handles.supervisor, handles.events
        self._reference, self._hold, self._disable = handles.reference, hold, disable
        self.safety = handles.rig.safety
        self.token: str | None = None
        self.holder = ANONYMOUS
        self.expires = 0.0
        self.ttl = self.safety.lease_ttl_s  # the default a client may shorten or lengthen
        self.ttl_active = self.ttl
        self.unleased_since: float | None = None  # since when an enabled arm has held with no lease holder
        self._told_enable = 0  # the enabled period (Supervisor.enables) whose unleased note was given
        self.renewals, self.renewed_at = 0, 0.0  # the holder's renewals of this lease, the last one's time [s]
        self.held_until = 0.0  # [s] a messenger restart's grace: the holder's ttl from the new one's readiness
        # Whether the messenger that carries the renewals is down or restarting now (set by the
        # loop's port, which looks at it when asked); None: a loop served by no messenger.
        self.carrier_down: Callable[[], bool] | None = None
        self._ticked = handles.clock.now()  # [s] the last tick: a longer gap than PAUSE_S is a pause of the loop

    @property
    def held(self) -> bool:
        return self.token is not None

    def acquire(self, client: Identity, ttl: float) -> dict:
        if client.role == OBSERVER:
            raise CommandFailed(P.FORBIDDEN, f"key {client} is an observer: it may read, watch and e-stop, never "
                                             f"take the lease", {"reason": "role", "role": OBSERVER})
        if self.token is not None:
            now = self._clock.now()
            who = f"key {self.holder.name!r}" if self.holder.name else "another client"
            if self.renewals:
                keeping = (f"and keeps renewing it (last {now - self.renewed_at:.1f} s ago, "
                           f"{self.renewals} renewal{'s' if self.renewals != 1 else ''} so far): "
                           f"it is theirs until they release it or stop renewing for {self.ttl_active:g} s")
            else:
                keeping = f"for up to {self.expires - now:.1f} s more unless they renew it"
            raise CommandFailed(P.LEASE_HELD, f"{who} holds the lease {keeping}",
                                {"reason": "held", "holder": self.holder.name})
        self.token, self.holder, self.ttl_active = secrets.token_hex(16), client, ttl
        self.expires = self._clock.now() + ttl
        self.renewals, self.held_until = 0, 0.0
        self._tell("acquire", f"for {ttl:g} s at a time")
        return {"lease": self.token, "ttl_s": ttl}

    def renew(self) -> dict:
        self.renewed_at = self._clock.now()
        self.renewals += 1
        self.expires = self.renewed_at + self.ttl_active
        return {"ttl_s": self.ttl_active}

    def release(self) -> dict:
        """Hand the lease back; a client that leaves the arm enabled is told what will become
        of it, and whether this is the first time in this enabled period (``first``: one-shot
        commands each hand the lease back, and their user is told once)."""
        self.token, self.unleased_since = None, None
        self._tell("release", "handed back")
        supervisor = self._supervisor
        if not supervisor.enabled:
            return {}
        first, self._told_enable = self._told_enable != supervisor.enables, supervisor.enables
        if self.safety.unleased_action == "hold":
            note = 'the arm stays enabled with no client holding the lease (rig file: unleased_action = "hold")'
        else:
            note = (f"the arm stays enabled with no client holding the lease: it is disabled once it has held "
                    f"{self.safety.unleased_grace_s:g} s with none (rig file [safety] unleased_grace_s)")
        return {"unleased": {"action": self.safety.unleased_action, "grace_s": self.safety.unleased_grace_s,
                             "note": note, "first": first}}

    def revoke(self, key: str, why: str = "removed") -> dict:
        """End the lease now if key ``key`` holds it: the key has left the allow-list, or its
        name now has another key or role (``why``: ``removed``, ``changed``; the messenger's
        ``lease.revoke`` at a reload). Its holder was in charge of what the arm
        does, so that stops too: an enabled arm holds where it is (as ``abort``) and the
        unleased policy runs from now (a ``"disable"`` grace time starts). One string
        comparison when the key holds no lease."""
        if self.token is None or self.holder.name != key:
            return {"ended": False, "cause": ""}
        self.token = None
        cause = (f"key {key!r} was revoked while it held the lease: the lease ended" if why == "removed" else
                 f"key {key!r} was given another key or role while it held the lease: the lease ended (take it "
                 f"again with the new key, as an operator)")
        if self._supervisor.enabled:
            stopped = "the running reference was stopped and " if self._reference()[1] > 0.0 else ""
            self._hold()
            action = self.safety.unleased_action
            if action == "disable":
                self.unleased_since = self._clock.now()
                policy = f"disabled after {self.safety.unleased_grace_s:g} s unless a client takes the lease"
            else:
                policy = "held until a client takes the lease"
            cause += (f"; {stopped}the arm holds where it is with no lease holder "
                      f"(unleased_action = \"{action}\": {policy})")
        self._events.add({"kind": "lease_revoked", "key": key, "cause": cause})
        return {"ended": True, "cause": cause}

    def check(self, token, client: Identity) -> None:
        """Refuse a command that needs the lease unless ``client`` holds it with ``token``."""
        if self.token is None:
            raise CommandFailed(P.NO_LEASE, "this command needs the lease: send lease.acquire first",
                                {"reason": "no_lease", "lease_held": False})
        if token is None:
            raise CommandFailed(P.NO_LEASE, "this command needs the lease token in the request's 'lease' field (a "
                                            "client holds the lease: if it is you, send its token)",
                                {"reason": "no_token", "lease_held": True})
        if token != self.token:
            raise CommandFailed(P.NO_LEASE, "the lease token does not match: another client holds the lease",
                                {"reason": "wrong_token", "lease_held": True})
        if client.name != self.holder.name:
            raise CommandFailed(P.FORBIDDEN, f"the lease was taken by key {self.holder}; this request comes from "
                                             f"key {client}: a lease token is no use to another key",
                                {"reason": "other_key", "holder": self.holder.name})

    def tick(self) -> None:
        """Once a cycle: a lapsed lease trips an enabled arm; an unleased one that has held
        for the grace time gets the rig file's action."""
        supervisor = self._supervisor
        now = self._clock.now()
        paused, self._ticked = now - self._ticked, now
        if self.token is not None:
            if paused > PAUSE_S:  # the loop did not cycle: its holder's renewals could not be taken
                self.expires += paused
            if now > self.expires and now > self.held_until and not self._held_over(now):
                self.token = None
                self._tell("expire", f"not renewed within {self.ttl_active:g} s")
                if supervisor.enabled:
                    supervisor.trip(f"lease lost: the controlling client ({self.holder}) stopped renewing it")
        elif supervisor.enabled:
            self._unleased()

    def _tell(self, action: str, cause: str) -> None:
        """The ``lease`` event: ``action`` (acquire, release, expire) by its holder."""
        self._events.add({"kind": "lease", "action": action, "holder": str(self.holder), "cause": cause})

    def _held_over(self, now: float) -> bool:
        """The lease ran out while the messenger, which carries its renewals, is down or
        restarting: held, up to HOLD_S past its time (the port looks at the messenger once
        more now, so a death since its last look counts)."""
        return now - self.expires <= HOLD_S and self.carrier_down is not None and self.carrier_down()

    def carried_again(self, now: float) -> None:
        """A new messenger is ready: the holder has its ttl from ``now`` to renew (within HOLD_S
        of the lease's own time)."""
        if self.token is not None:
            self.held_until = max(self.held_until, min(now + self.ttl_active, self.expires + HOLD_S))

    def _unleased(self) -> None:
        if self.safety.unleased_action == "hold" or self._reference()[1] > 0.0:
            self.unleased_since = None
            return
        now = self._clock.now()
        if self.unleased_since is None:
            self.unleased_since = now
        elif now - self.unleased_since > self.safety.unleased_grace_s:
            self.unleased_since = None
            self._events.add(
                {"kind": "unleased", "cause": f"the arm held {self.safety.unleased_grace_s:g} s with no client holding "
                                              f"the lease: disabled (rig file [safety] unleased_action)"})
            self._disable()

    def disable_in(self) -> float | None:
        """Seconds until an unleased, holding arm is disabled (None if that is not under way)."""
        if self.unleased_since is None or self.token is not None or not self._supervisor.enabled:
            return None
        return max(self.safety.unleased_grace_s - (self._clock.now() - self.unleased_since), 0.0)
