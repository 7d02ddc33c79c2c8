"""A Python client for pneumad, over the documented protocol (docs/protocol.md).

    from daemon.client.client import Client
    with Client() as c:
        c.acquire_lease()
        c.enable()
        c.path("circle", duration_s=40)

Replies are matched to requests by id; a reply that never comes raises TimeoutError
instead of hanging. A command whose reply is deferred (planned or built beside the loop:
``catalog.DEFERRED``) is waited for as long as the daemon's ``describe`` says such
work may take. ``keep_lease()`` renews the lease from a background thread. The commands
themselves, one method each, are :class:`daemon.client.command_methods.CommandMethods`.

A daemon with keys (docs/protocol.md, "Keys") needs ``key_file``: the client's
``NAME.key_secret``, which names the daemon's public key itself, or with ``server_key_file``
(the daemon's ``server.key``); ``PNEUMAD_KEY`` and ``PNEUMAD_SERVER_KEY`` in the environment
give them too. ``PNEUMAD_COMMAND``, ``PNEUMAD_CONTROL`` and ``PNEUMAD_TELEMETRY`` give the
endpoints where no argument does (else the protocol's defaults, tcp://127.0.0.1:5560-5562).
A daemon that refuses the key (unknown, revoked, or none given) is reported as
:class:`KeyRefused`, not as a silent time-out.
"""
from __future__ import annotations

import csv
import itertools
import os
import threading
import time

import msgpack
import zmq
from zmq.utils.monitor import recv_monitor_message

from daemon.client.command_methods import CommandMethods
from daemon.client.feeds import LatestState, Subscription
from daemon.wire import catalog, protocol
from daemon.wire.cycle_layout import CycleLayout
from daemon.wire.keys import secure_client
from daemon.wire.protocol import DEFAULT_COMMAND, DEFAULT_CONTROL, DEFAULT_TELEMETRY


ENDPOINT_VARIABLES = {"command": "PNEUMAD_COMMAND", "control": "PNEUMAD_CONTROL", "telemetry": "PNEUMAD_TELEMETRY"}
_DEFAULT_ENDPOINTS = {"command": DEFAULT_COMMAND, "control": DEFAULT_CONTROL, "telemetry": DEFAULT_TELEMETRY}


def default_endpoint(name: str) -> str:
    """The endpoint of socket ``name`` when none is given: its environment variable, else the
    protocol's default."""
    return os.environ.get(ENDPOINT_VARIABLES[name]) or _DEFAULT_ENDPOINTS[name]


class RemoteError(RuntimeError):
    """The daemon answered with an error."""

    def __init__(self, code: str, message: str, data: dict | None = None):
        super().__init__(f"{code}: {message}")
        self.code, self.message, self.data = code, message, data


class Interrupted(Exception):
    """Ctrl-C in a client routine. Its message says in one line what the routine left running
    on the daemon (and the command that stops it) or what it stopped; pneumactl prints it and
    exits 130, as a shell does for SIGINT."""


def abort_started(client: "Client", what: str) -> str:
    """Abort the reference a client routine started (it holds the lease) and say so: the
    sentence an :class:`Interrupted` routine ends with. Sent on the command socket, behind the
    routine's own requests: a move it asked for that is still being planned when Ctrl-C comes
    is overtaken by the abort, never started after it (the control socket could pass it)."""
    try:
        client.call("abort")
    except (RemoteError, TimeoutError) as exc:
        return f"{what} could not be aborted ({exc}): `pneumactl abort` stops it"
    return f"{what} was aborted: the arm holds where it is, enabled"


class RequestTooLarge(ValueError):
    """A request over the daemon's message size, refused here before it is sent."""


def too_large(cmd: str, args: dict, size: int) -> str:
    """Why a request of ``size`` bytes is not sent: the limit, and each list of it that holds
    more than the catalog's maximum."""
    spec = catalog.COMMANDS.get(cmd)
    most = {a.name: a.high for a in (spec.args if spec else ()) if a.kind == "list" and a.high is not None}
    over = [f"{name!r} holds {len(value)} items, at most {most[name]:g}" for name, value in args.items()
            if name in most and isinstance(value, list) and len(value) > most[name]]
    return (f"{cmd!r} is {size} bytes, over the daemon's limit of {protocol.MAX_MESSAGE_BYTES} bytes a request: "
            f"not sent" + (f" ({'; '.join(over)})" if over else ""))


class KeyRefused(ConnectionError):
    """The daemon would not complete the CURVE handshake with this client."""


_HANDSHAKE_EVENTS = (zmq.EVENT_HANDSHAKE_FAILED_AUTH | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
                     | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL | zmq.EVENT_HANDSHAKE_SUCCEEDED)

# each monitor's own inproc name: pyzmq's default names it by the socket's descriptor, which a
# new socket reuses while a closed one's monitor may still hold the name (closing is done by
# libzmq's reaper thread, late on a busy machine): "Address already in use"
_MONITORS = itertools.count(1)


class Client(CommandMethods):
    """A connection to one daemon: its sockets, each request matched to its reply, the lease
    kept, telemetry subscribed; the commands themselves are :class:`CommandMethods`'."""

    def __init__(self, command: str | None = None, control: str | None = None,
                 telemetry: str | None = None, timeout: float = 2.0, context: zmq.Context | None = None,
                 key_file: str | None = None, server_key_file: str | None = None):
        self.context = context or zmq.Context.instance()
        command = command or default_endpoint("command")
        control = control or default_endpoint("control")
        telemetry = telemetry or default_endpoint("telemetry")
        self.endpoints = {"command": command, "control": control, "telemetry": telemetry}
        self.timeout = timeout
        self.key_file = key_file or os.environ.get("PNEUMAD_KEY") or None
        self.server_key_file = server_key_file or os.environ.get("PNEUMAD_SERVER_KEY") or None
        self._monitors: dict[str, zmq.Socket] = {}
        self._ids = itertools.count(1)
        self._sockets = {name: self._dealer(ep) for name, ep in (("command", command), ("control", control))}
        self._lock = threading.Lock()
        self.lease: str | None = None
        self._keeper: threading.Thread | None = None
        self._stop_keeping = threading.Event()  # set: the keeper thread stops at once, not after its sleep
        self._deferred_timeout: float | None = None  # from describe, on the first deferred command
        self._layout: CycleLayout | None = None  # the cycle record's, from describe (layout())

    def _dealer(self, endpoint: str) -> zmq.Socket:
        sock = self.context.socket(zmq.DEALER)
        sock.setsockopt(zmq.LINGER, 0)
        self._secure(sock)
        self._monitors[endpoint] = sock.get_monitor_socket(_HANDSHAKE_EVENTS, f"inproc://client-handshakes.{next(_MONITORS)}")
        sock.connect(endpoint)
        return sock

    def _secure(self, sock: zmq.Socket) -> None:
        if self.key_file:
            secure_client(sock, self.key_file, self.server_key_file)

    def _refused(self, endpoint: str) -> KeyRefused | None:
        """What the handshakes with ``endpoint`` said so far: a refusal, if the last was one."""
        monitor, last = self._monitors[endpoint], None
        while monitor.poll(0):
            last = recv_monitor_message(monitor)["event"]
        if last in (None, zmq.EVENT_HANDSHAKE_SUCCEEDED):
            return None
        if not self.key_file:
            return KeyRefused(f"{endpoint} wants a key (the daemon runs with CURVE keys): give --key FILE or set "
                              f"PNEUMAD_KEY (docs/protocol.md, Keys)")
        return KeyRefused(f"{endpoint} refused the key in {self.key_file}: it is not allowed there (unknown or "
                          f"revoked), or the daemon's public key given is not that daemon's")

    def close(self) -> None:
        self._stop_keeping.set()
        if self._keeper is not None:
            self._keeper.join()
        for sock in self._sockets.values():
            sock.disable_monitor()
            sock.close(linger=0)
        for monitor in self._monitors.values():
            monitor.close(linger=0)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.lease is not None:
            try:
                self.release_lease()
            except (RemoteError, TimeoutError):
                pass
        self.close()

    # -- requests -------------------------------------------------------------------------
    def call(self, cmd: str, args: dict | None = None, control: bool = False, timeout: float | None = None):
        """Send one request and wait for its reply; raise RemoteError or TimeoutError."""
        if timeout is None and cmd in catalog.DEFERRED:
            timeout = max(self.timeout, self.deferred_timeout())
        with self._lock:
            sock = self._sockets["control" if control else "command"]
            request_id = next(self._ids)
            endpoint = self.endpoints["control" if control else "command"]
            limit = self.timeout if timeout is None else timeout
            deadline = time.monotonic() + limit
            # A DEALER with no live connection (its handshake refused) would block in send.
            if not sock.poll(limit * 1e3, zmq.POLLOUT):
                self._unanswered(cmd, endpoint, limit)
            request = protocol.encode_request(request_id, cmd, args, self.lease)
            if len(request) > protocol.MAX_MESSAGE_BYTES:
                raise RequestTooLarge(too_large(cmd, args or {}, len(request)))
            try:
                sock.send(request, zmq.NOBLOCK)
            except zmq.Again:  # the connection went between the poll and the send: a refused handshake
                self._unanswered(cmd, endpoint, limit)
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not sock.poll(remaining * 1e3):
                    self._unanswered(cmd, endpoint, limit)
                reply = msgpack.unpackb(sock.recv_multipart()[-1], raw=False)
                if reply.get("id") == request_id:
                    break  # earlier replies that arrived after their timeout are dropped
        if not reply.get("ok"):
            error = reply.get("error", {})
            raise RemoteError(error.get("code", "?"), error.get("message", ""), error.get("data"))
        return reply.get("result")

    def _unanswered(self, cmd: str, endpoint: str, limit: float):
        """Raise why there is no reply: the daemon refused this client's key, or silence."""
        refused = self._refused(endpoint)
        if refused is not None:
            raise refused
        raise TimeoutError(f"no reply to {cmd!r} within {limit} s from {endpoint}")

    def deferred_timeout(self) -> float:
        """How long a deferred reply may take [s]: the daemon's own limit, and a margin."""
        if self._deferred_timeout is None:
            self._deferred_timeout = float(self.describe()["deferred_timeout_s"]) + 2.0
        return self._deferred_timeout

    def joint_units(self) -> list[tuple[str, str]]:
        """The rig's joints in order, each with the unit its positions are given in (``deg`` on a
        rotary joint, ``mm`` on a linear one): their position fields' display units."""
        layout = self.layout()
        return [(j["name"], layout[f"{j['name']}.position"].display[0]) for j in self.describe()["joints"]]

    def layout(self, message: dict | None = None) -> CycleLayout:
        """The daemon's cycle record layout (``describe``'s ``cycle_layout``): what each column
        of a ``state`` message is, its unit and display unit. Read once; read again when
        ``message`` (a ``state`` message) names another layout (the daemon was restarted with
        another rig file)."""
        if self._layout is None or (message is not None and message.get("layout") != self._layout.id):
            described = self.describe()
            self._layout = CycleLayout.from_describe(described["cycle_layout"])
            if self._layout.id != described["cycle_layout_id"]:
                raise ValueError(f"describe's cycle_layout does not match its cycle_layout_id "
                                 f"({self._layout.id} != {described['cycle_layout_id']})")
        return self._layout

    def sample(self, timeout: float | None = None) -> dict:
        """The latest cycle's record by field name (SI values, ``mode`` by name), from the next
        ``state`` message (about 10 ms away); TimeoutError if none comes within ``timeout``."""
        with self.latest() as feed:
            return feed.row(timeout)

    def latest(self) -> LatestState:
        """A subscription to the ``state`` topic whose :meth:`LatestState.row` is the newest
        cycle record (for a client that reads it often: one subscription, not one a read)."""
        return LatestState(self)

    # -- lease ----------------------------------------------------------------------------
    def acquire_lease(self, ttl_s: float | None = None):
        result = self.call("lease.acquire", {} if ttl_s is None else {"ttl_s": ttl_s})
        self.lease = result["lease"]
        return result

    def renew_lease(self):
        return self.call("lease.renew")

    def release_lease(self):
        try:
            return self.call("lease.release")
        finally:
            self.lease = None
            self._stop_keeping.set()

    def keep_lease(self, every_s: float = 0.5) -> None:
        """Renew the lease from a background thread until close() or the lease is handed
        back, through sockets of its own (the lease is the key's, not the socket's): a renewal
        never waits behind a request in progress, and a deferred one can take seconds. A
        renewal unanswered within ``2 * every_s`` is sent again (one lost with a messenger
        that died is retried well within the lease's ttl after the new one is ready)."""
        self._stop_keeping = stop = threading.Event()

        def renew():
            renewer = Client(**self.endpoints, timeout=min(self.timeout, 2.0 * every_s), context=self.context,
                             key_file=self.key_file, server_key_file=self.server_key_file)
            try:
                while not stop.is_set() and self.lease is not None:
                    renewer.lease = self.lease
                    try:
                        renewer.renew_lease()
                    except (RemoteError, TimeoutError):
                        pass
                    stop.wait(every_s)
            finally:
                renewer.lease = None  # the owner hands it back
                renewer.close()

        self._keeper = threading.Thread(target=renew, name="pneumad-lease", daemon=True)
        self._keeper.start()

    # -- telemetry ------------------------------------------------------------------------
    def subscribe(self, topics=(b"state", b"stats", b"event", b"internals")) -> Subscription:
        return Subscription(self.context, self.endpoints["telemetry"], topics, self._secure)


def read_waypoints(path, joints) -> dict:
    """A waypoint CSV file as ``waypoints()`` arguments. The header names the columns:
    ``duration_s`` (time from the previous point; ignored on the first row), then either
    ``x_mm,y_mm`` (Cartesian) or one column per joint named ``<joint>_deg`` (rotary) or
    ``<joint>_mm`` (linear), in any order. ``joints`` is the rig's ``[(name, unit)]`` in its
    order (unit ``deg`` or ``mm``: :meth:`Client.joint_units`); the columns are read by name
    into ``positions`` in that order, and a name that is not a joint's (or not in its unit),
    a joint missing or a column given twice is refused."""
    with open(path, newline="") as f:
        rows = [r for r in csv.reader(line for line in f if line.strip() and not line.startswith("#"))]
    if len(rows) < 3 or rows[0][0].strip() != "duration_s":
        raise ValueError(f"{path}: expected a header starting with duration_s and at least two points")
    columns = [c.strip() for c in rows[0][1:]]
    if any(len(r) != len(rows[0]) for r in rows[1:]):
        raise ValueError(f"{path}: every row needs {len(rows[0])} values, as the header names columns")
    try:
        values = [[float(v) for v in r] for r in rows[1:]]
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    points, durations = [v[1:] for v in values], [v[0] for v in values[1:]]
    if columns == ["x_mm", "y_mm"]:
        return {"xy_mm": points, "durations_s": durations}
    order = [columns.index(name) for name in _joint_columns(path, columns, joints)]
    return {"positions": [[p[i] for i in order] for p in points], "durations_s": durations}


def _joint_columns(path, columns: list[str], joints) -> list[str]:
    """The joint columns' names in the rig's order, once each of ``columns`` is checked."""
    wanted = [f"{name}_{unit}" for name, unit in joints]
    expected = ",".join(["duration_s", *wanted])
    twice = sorted({c for c in columns if columns.count(c) > 1})
    unknown = [c for c in columns if c not in wanted]
    missing = [c for c in wanted if c not in columns]
    for problem, names in (("given twice", twice), ("not this rig's joints", unknown), ("missing", missing)):
        if names:
            raise ValueError(f"{path}: column{'s' if len(names) > 1 else ''} {','.join(names)} {problem}: the "
                             f"header must be duration_s,x_mm,y_mm or name each joint once by its unit, "
                             f"{expected} (any order)")
    return wanted
