"""The wire protocol (docs/protocol.md): msgpack maps over ZeroMQ, versioned.

Request ``{v, id, cmd, args?, lease?}``; reply ``{v, id, ok: true, result}`` or
``{v, id, ok: false, error: {code, message, data?}}``. Decoding is bounded (sizes, lengths, no
extension types), so a hostile frame costs little and gets a clear error.
"""
from __future__ import annotations

import msgpack

VERSION = 1
DEFAULT_COMMAND = "tcp://127.0.0.1:5560"  # the daemon's endpoints unless told otherwise (docs/protocol.md)
DEFAULT_CONTROL = "tcp://127.0.0.1:5561"
DEFAULT_TELEMETRY = "tcp://127.0.0.1:5562"
MAX_MESSAGE_BYTES = 64 * 1024  # a larger request is answered bad_message, never read further
MAX_FRAME_BYTES = 4 * MAX_MESSAGE_BYTES  # ZeroMQ drops a larger frame (and its peer) unread: what a peer may queue

# Error codes a client can branch on.
BAD_MESSAGE = "bad_message"  # not msgpack, not a map, or a field of the wrong type
BAD_VERSION = "bad_version"
UNKNOWN_COMMAND = "unknown_command"
BAD_ARGS = "bad_args"  # arguments missing, of the wrong type or out of range
NO_LEASE = "no_lease"  # the command moves the arm and the caller does not hold the lease
LEASE_HELD = "lease_held"  # another client holds the lease
BAD_STATE = "bad_state"  # not allowed in the daemon's present state
REFUSED = "refused"  # valid, but unsafe or infeasible on this rig
BUSY = "busy"  # work is being prepared beside the loop (a plan, a controller); ask again when its reply is in
LOOP_STALLED = "loop_stalled"  # from the messenger: the loop has stopped cycling
FORBIDDEN = "forbidden"  # the client's key may not do this (its role, a lease taken by another key, a revoked key)
INTERNAL = "internal"  # a bug: reported, never fatal
ERROR_CODES = (BAD_MESSAGE, BAD_VERSION, UNKNOWN_COMMAND, BAD_ARGS, NO_LEASE, LEASE_HELD, BAD_STATE, REFUSED, BUSY,
               LOOP_STALLED, FORBIDDEN, INTERNAL)


class ProtocolError(Exception):
    def __init__(self, code: str, message: str, request_id=None):
        super().__init__(message)
        self.code, self.message, self.request_id = code, message, request_id

    def __reduce__(self):  # raised in the planner process too
        return type(self), (self.code, self.message, self.request_id)


_LIMITS = dict(max_str_len=MAX_MESSAGE_BYTES, max_bin_len=MAX_MESSAGE_BYTES, max_array_len=4096, max_map_len=256,
               max_ext_len=0)
_MAP_MARKERS = frozenset(range(0x80, 0x90)) | {0xDE, 0xDF}  # fixmap, map 16, map 32


def decode_request(payload: bytes, start: int = 0) -> dict:
    """A validated request envelope, or :class:`ProtocolError`. ``args`` is not decoded here
    but located (``args_span``, byte offsets in ``payload``): the loop decodes only the small
    arguments of its own commands (:func:`decode_args`), and a planned command's arguments,
    up to a 64 KiB list of waypoints, are decoded by the planner beside the loop. The request
    starts at ``start`` (after the messenger's few bytes saying who sent it)."""
    unpacker = msgpack.Unpacker(raw=False, strict_map_key=True, max_buffer_size=MAX_MESSAGE_BYTES, **_LIMITS)
    msg, span = {}, None
    unpacker.feed(memoryview(payload)[start:])
    try:
        entries = unpacker.read_map_header()
    except msgpack.OutOfData:
        raise ProtocolError(BAD_MESSAGE, "not a msgpack message: empty or cut short") from None
    except Exception as exc:
        raise ProtocolError(BAD_MESSAGE, f"the message must be a msgpack map ({exc})") from None
    try:
        for _ in range(entries):
            key = unpacker.unpack()
            if key == "args":
                begin = unpacker.tell()
                unpacker.skip()
                span = (start + begin, start + unpacker.tell())
            else:
                msg[key] = unpacker.unpack()
        if start + unpacker.tell() != len(payload):
            raise ValueError("extra data after the message")
    except Exception as exc:  # msgpack raises several types for malformed input
        raise ProtocolError(BAD_MESSAGE, f"not a msgpack message: {type(exc).__name__}: {exc}") from None
    request_id = msg.get("id")
    if not (isinstance(request_id, int) and not isinstance(request_id, bool)
            or isinstance(request_id, str) and len(request_id) <= 128):
        raise ProtocolError(BAD_MESSAGE, "'id' must be an integer or a string of at most 128 characters")
    version = msg.get("v")
    if isinstance(version, bool) or not isinstance(version, int):
        raise ProtocolError(BAD_MESSAGE, f"'v' must be the protocol version, an integer (this daemon speaks "
                                         f"{VERSION})", request_id)
    if version != VERSION:
        raise ProtocolError(BAD_VERSION, f"protocol version {version} is not supported (this daemon speaks "
                                         f"{VERSION})", request_id)
    cmd = msg.get("cmd")
    if not isinstance(cmd, str):
        raise ProtocolError(BAD_MESSAGE, "'cmd' must be a string", request_id)
    if span is not None and payload[span[0]] not in _MAP_MARKERS:
        raise ProtocolError(BAD_MESSAGE, "'args' must be a map", request_id)
    lease = msg.get("lease")
    if lease is not None and not isinstance(lease, str):
        raise ProtocolError(BAD_MESSAGE, "'lease' must be a string", request_id)
    unknown = set(msg) - {"v", "id", "cmd", "lease"}
    if unknown:
        raise ProtocolError(BAD_MESSAGE, f"unknown envelope field {sorted(map(str, unknown))[0][:80]!r}", request_id)
    return {"id": request_id, "cmd": cmd, "lease": lease, "payload": payload, "args_span": span}


def request_id_of(payload: bytes):
    """A request's id as the loop would echo it (None if it cannot be read), for a reply given
    outside the loop (the messenger, the recorder)."""
    try:
        return decode_request(payload)["id"]
    except ProtocolError as exc:
        return exc.request_id


def too_large(payload: bytes) -> bytes:
    """The reply to a request over ``MAX_MESSAGE_BYTES`` (up to ``MAX_FRAME_BYTES``: the
    messenger's, never the loop's): ``bad_message`` naming both sizes, with the request's id
    where its envelope can be read (else null)."""
    request_id = None
    unpacker = msgpack.Unpacker(raw=False, strict_map_key=True, max_buffer_size=len(payload), max_ext_len=0)
    unpacker.feed(payload)
    try:
        for _ in range(unpacker.read_map_header()):
            if unpacker.unpack() == "id":
                found = unpacker.unpack()
                number = isinstance(found, int) and not isinstance(found, bool)
                short = isinstance(found, str) and len(found) <= 128
                request_id = found if number or short else None  # the ids decode_request takes
                break
            unpacker.skip()
    except Exception:  # not a msgpack map: the id stays unknown
        pass
    return encode_error(request_id, BAD_MESSAGE, f"the request is {len(payload)} bytes, over the daemon's limit of "
                                                 f"{MAX_MESSAGE_BYTES} bytes: nothing was done")


def decode_args(request: dict) -> dict:
    """The request's ``args`` map (empty when it has none)."""
    span = request["args_span"]
    if span is None:
        return {}
    try:
        return msgpack.unpackb(request["payload"][span[0]:span[1]], raw=False, strict_map_key=True, **_LIMITS)
    except Exception as exc:  # too long, too deep, a non-string key ...
        raise ProtocolError(BAD_MESSAGE, f"'args' cannot be read: {type(exc).__name__}: {exc}",
                            request["id"]) from None


class Packed(bytes):
    """A result packed as msgpack once (a large reply that never changes: ``describe``), which
    :func:`encode_result` splices in rather than packing it again per request."""

    @classmethod
    def of(cls, result) -> "Packed":
        return cls(msgpack.packb(result))


def encode_result(request_id, result) -> bytes:
    if isinstance(result, Packed):  # "result" is the map's last key: its packed nil (0xc0) is the last byte
        return msgpack.packb({"v": VERSION, "id": request_id, "ok": True, "result": None})[:-1] + result
    return msgpack.packb({"v": VERSION, "id": request_id, "ok": True, "result": result})


def encode_error(request_id, code: str, message: str, data: dict | None = None) -> bytes:
    error = {"code": code, "message": message}
    if data is not None:
        error["data"] = data
    return msgpack.packb({"v": VERSION, "id": request_id, "ok": False, "error": error})


def encode_request(request_id, cmd: str, args: dict | None = None, lease: str | None = None) -> bytes:
    msg = {"v": VERSION, "id": request_id, "cmd": cmd, "args": args or {}}
    if lease is not None:
        msg["lease"] = lease
    return msgpack.packb(msg)
