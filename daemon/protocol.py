"""The wire protocol (docs/protocol.md): msgpack maps over ZeroMQ, versioned.

Request ``{v, id, cmd, args?, lease?}``; reply ``{v, id, ok: true, result}`` or
``{v, id, ok: false, error: {code, message}}``. Decoding is bounded (sizes, lengths, no
extension types), so a hostile frame costs little and gets a clear error.
"""
from __future__ import annotations

import msgpack

VERSION = 1
MAX_MESSAGE_BYTES = 64 * 1024  # larger frames are dropped by ZeroMQ before they are read

# Error codes a client can branch on.
BAD_MESSAGE = "bad_message"  # not msgpack, not a map, or a field of the wrong type
BAD_VERSION = "bad_version"
UNKNOWN_COMMAND = "unknown_command"
BAD_ARGS = "bad_args"  # arguments missing, of the wrong type or out of range
NO_LEASE = "no_lease"  # the command moves the arm and the caller does not hold the lease
LEASE_HELD = "lease_held"  # another client holds the lease
BAD_STATE = "bad_state"  # not allowed in the daemon's present state
REFUSED = "refused"  # valid, but unsafe or infeasible on this rig
BUSY = "busy"  # a controller is being prepared off the loop; ask again when its reply is in
INTERNAL = "internal"  # a bug: reported, never fatal


class ProtocolError(Exception):
    def __init__(self, code: str, message: str, request_id=None):
        super().__init__(message)
        self.code, self.message, self.request_id = code, message, request_id


def decode_request(payload: bytes) -> dict:
    """A validated request envelope, or :class:`ProtocolError`."""
    try:
        msg = msgpack.unpackb(payload, raw=False, strict_map_key=True, max_str_len=MAX_MESSAGE_BYTES,
                              max_bin_len=MAX_MESSAGE_BYTES, max_array_len=4096, max_map_len=256,
                              max_ext_len=0)
    except Exception as exc:  # msgpack raises several types for malformed input
        raise ProtocolError(BAD_MESSAGE, f"not a msgpack message: {type(exc).__name__}: {exc}") from None
    if not isinstance(msg, dict):
        raise ProtocolError(BAD_MESSAGE, f"the message must be a map, got {type(msg).__name__}")
    request_id = msg.get("id")
    if not (isinstance(request_id, int) and not isinstance(request_id, bool)
            or isinstance(request_id, str) and len(request_id) <= 128):
        raise ProtocolError(BAD_MESSAGE, "'id' must be an integer or a string of at most 128 characters")
    if msg.get("v") != VERSION:
        raise ProtocolError(BAD_VERSION, f"protocol version {msg.get('v')!r} is not supported (this daemon speaks "
                                         f"{VERSION})", request_id)
    cmd = msg.get("cmd")
    if not isinstance(cmd, str):
        raise ProtocolError(BAD_MESSAGE, "'cmd' must be a string", request_id)
    args = msg.get("args", {})
    if not isinstance(args, dict):
        raise ProtocolError(BAD_MESSAGE, "'args' must be a map", request_id)
    lease = msg.get("lease")
    if lease is not None and not isinstance(lease, str):
        raise ProtocolError(BAD_MESSAGE, "'lease' must be a string", request_id)
    unknown = set(msg) - {"v", "id", "cmd", "args", "lease"}
    if unknown:
        raise ProtocolError(BAD_MESSAGE, f"unknown envelope field {sorted(map(str, unknown))[0]!r}", request_id)
    return {"id": request_id, "cmd": cmd, "args": args, "lease": lease}


def encode_result(request_id, result) -> bytes:
    return msgpack.packb({"v": VERSION, "id": request_id, "ok": True, "result": result})


def encode_error(request_id, code: str, message: str) -> bytes:
    return msgpack.packb({"v": VERSION, "id": request_id, "ok": False, "error": {"code": code, "message": message}})


def encode_request(request_id, cmd: str, args: dict | None = None, lease: str | None = None) -> bytes:
    msg = {"v": VERSION, "id": request_id, "cmd": cmd, "args": args or {}}
    if lease is not None:
        msg["lease"] = lease
    return msgpack.packb(msg)
