"""A request as the messenger hands it to the loop through the command or control ring: who
sent it, its envelope as the messenger decoded and checked it (id, command, lease), where its
arguments lie, then the request's own bytes.

The envelope is decoded once, in the messenger (:func:`daemon.wire.protocol.decode_request`);
the loop reads this small header with one msgpack call instead of walking the request again,
and decodes the arguments only for its own few small commands (a planned command's are decoded
by the planner, from the same bytes).

    entry = header length (2 bytes, little-endian) + header + request
    header = msgpack [role index, key name, id, cmd, lease, args begin, args end]   (-1, -1: no args)
"""
from __future__ import annotations

from functools import lru_cache

import msgpack

from daemon.wire.keys import ROLES, Identity

_LENGTH = 2


def pack(identity: Identity, request: dict) -> bytes:
    """The ring entry for a ``request`` decoded by :func:`~daemon.wire.protocol.decode_request`
    (its ``payload`` is the request's bytes, ``args_span`` offsets in them)."""
    begin, end = request["args_span"] or (-1, -1)
    header = msgpack.packb([ROLES.index(identity.role), identity.name, request["id"], request["cmd"],
                            request["lease"], begin, end])
    return len(header).to_bytes(_LENGTH, "little") + header + request["payload"]


def unpack(entry: bytes) -> tuple[Identity, dict]:
    """(who sent it, the request as :func:`~daemon.wire.protocol.decode_request` gives it, with
    ``payload`` the whole entry and ``args_span`` offsets in it) from a ring entry. Only the
    messenger writes these: anything else raises ValueError (or another msgpack error)."""
    size = int.from_bytes(entry[:_LENGTH], "little")
    role, name, request_id, cmd, lease, begin, end = msgpack.unpackb(entry[_LENGTH:_LENGTH + size])
    start = _LENGTH + size
    span = (start + begin, start + end) if begin >= 0 else None
    return _identity(name, role), {"id": request_id, "cmd": cmd, "lease": lease, "payload": entry,
                                         "args_span": span}


@lru_cache(maxsize=256)
def _identity(name: str, role: int) -> Identity:
    """The (frozen, so shareable) identity of an allowed key: built once, not per request."""
    return Identity(name, ROLES[role])
