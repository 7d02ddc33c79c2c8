"""Keys a reload removed, in the messenger: the loop told of each (``lease.revoke``, an
internal command of the catalog: a lease the key holds ends at once), a refusal said in the
daemon's log, and the moment the telemetry socket may be bound again.

Binding the publisher again is what cuts a revoked subscriber off; every allowed one must then
be admitted again and loses what is published meanwhile. So the socket is bound again only once
the loop has answered and cycled once more, its events of the revocation (the lease ended, the
reference stopped) published before it: subscribers see them. A loop that does not answer
(stalled) holds it back for at most ``REBIND_LIMIT_S``.
"""
from __future__ import annotations

import logging

import msgpack

from daemon.messenger.shared import OWED_LIMIT_S, Heartbeat
from daemon.wire import protocol, routed
from daemon.wire.keys import Identity
from daemon.wire.ring import Ring

REBIND_LIMIT_S = 1.0  # the longest a revoked subscriber goes on receiving after a reload [s]
log = logging.getLogger("pneumad")


class Revocations:
    def __init__(self, rings: dict[str, Ring], heartbeat: Heartbeat, tokens):
        self.rings, self.heartbeat, self._tokens = rings, heartbeat, tokens
        self.asked: dict[int, tuple[str, str, float]] = {}  # a lease.revoke's token -> (its key, who reloaded, when)
        self._awaited: set[int] = set()  # the control ring's lease.revoke tokens not answered yet
        self._rebind_by: float | None = None  # a re-bind pending: done at the latest then
        self._rebind_cycle: int | None = None  # ... or once the loop's heartbeat has passed this

    def revoke(self, ended: dict[str, str], who: Identity, now: float) -> None:
        """Tell the loop that each key in ``ended`` left the allow-list or changed (its name ->
        ``removed`` or ``changed``: another key or role; signed by ``who``, who reloaded), and
        hold the telemetry socket's re-bind until it has answered. Each goes
        on the control ring, ahead of any backlog of commands; and again on the command ring,
        behind the key's own requests taken before this reload: a ``lease.acquire`` of the key's
        waiting there is granted after the first and ended by the second."""
        for key, why in ended.items():
            request = protocol.decode_request(protocol.encode_request(f"revoke-{key}", "lease.revoke",
                                                                      {"key": key, "why": why}))
            entry = routed.pack(who, request)
            for ring in ("control", "command"):
                token = next(self._tokens)
                if self.rings[ring].put(token, entry):  # always room: requests are taken only while 64 KiB are free
                    self.asked[token] = (key, who.name, now)
                    if ring == "control":
                        self._awaited.add(token)
                else:
                    log.error("keys: could not tell the loop that key %r was revoked (its %s ring is full): a lease "
                              "it holds lapses only at its time to live", key, ring)
        self._rebind_by = now + REBIND_LIMIT_S
        self._rebind_cycle = None

    def answer(self, token: int, reply: bytes) -> bool:
        """Take the loop's reply ``token`` if it answers a ``lease.revoke`` (a lease it ended is
        its ``lease_revoked`` event, and so a line of the journal); whether it did."""
        asked = self.asked.pop(token, None)
        if asked is None:
            return False
        key, who, _ = asked
        answer = msgpack.unpackb(reply, raw=False)
        if not answer.get("ok"):
            log.error("keys: the loop did not end the lease of revoked key %r (keys reloaded by %s): %s", key, who,
                      answer.get("error"))
        if token in self._awaited:
            self._awaited.discard(token)
            if not self._awaited:  # its events are on the telemetry ring once it has cycled again
                self._rebind_cycle = self.heartbeat.read()
        return True

    def rebind_due(self, now: float) -> bool:
        """Whether the telemetry socket should be bound again now (ask before draining the
        telemetry ring: what the loop said of the revocation is in it by then)."""
        if self._rebind_by is None:
            return False
        answered = self._rebind_cycle is not None and self.heartbeat.read() > self._rebind_cycle
        if answered or now >= self._rebind_by:
            self._rebind_by = self._rebind_cycle = None
            self._awaited.clear()
            return True
        return False

    def expire(self, now: float) -> None:
        """Forget questions the loop never answered (a reply it could not queue)."""
        self.asked = {t: a for t, a in self.asked.items() if now - a[2] < OWED_LIMIT_S}
