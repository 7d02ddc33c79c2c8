"""The loop's side of the daemon's ZeroMQ endpoints (command, control, telemetry).

The sockets themselves live in the messenger process (:mod:`daemon.messenger.process`); the loop
reaches them through shared-memory rings, so all it does per message is a memory copy.
Each cycle, at its end, it serves every pending control-socket request (e-stop, abort,
disable, status, ping; at most ``MAX_CONTROL_PER_CYCLE``), then at most ``max_per_cycle``
command-socket requests, and queues each reply; telemetry is queued the same way. The
command stage has a budget in time too (``COMMAND_BUDGET_S``): once it is spent, what is
left waits for the next cycle, so a flood of the dearest requests (a status is about 100 us
on a loaded 2-core VM) costs a cycle about the budget and one request, never ten requests.
The first request of a cycle is always served: an e-stop at the head of its ring never
waits for a budget. A ring
that is full refuses: the message is dropped and counted (``telemetry_dropped``,
``reply_failures``), never waited for. Requests over ``protocol.MAX_MESSAGE_BYTES`` are answered
``bad_message`` by the messenger, frames over ``protocol.MAX_FRAME_BYTES`` dropped by ZeroMQ there
(the peer is disconnected): neither reaches the loop.

Each request arrives with who sent it and its envelope, decoded once by the messenger
(:mod:`daemon.wire.routed`). Which clients may connect at all is the messenger's
(CURVE, :mod:`daemon.messenger.guard`); :func:`security` says what a daemon's endpoints and keys add up
to, and refuses to bind past loopback with nobody's key checked unless told ``insecure``.
"""
from __future__ import annotations

import ctypes
import logging
import os
import shutil
import tempfile

from daemon.wire import protocol as P
from daemon.loop.commands import Commands
from daemon.wire import routed
from daemon.messenger.process import END, STALL_S, TOPICS, Heartbeat, Messenger, create_rings
from daemon.wire.watchdog_link import WatchdogLink
from daemon.planner.process import Deferred
from daemon.model.process import ModelProcess, wanted
from daemon.recorder.process import RecorderProcess, write_metadata
from daemon.wire.protocol import DEFAULT_COMMAND, DEFAULT_CONTROL, DEFAULT_TELEMETRY
from daemon.wire.cycle_layout import CycleLayout
from daemon.wire.loop_stats import StatsBanks
from daemon.wire.ring import Ring, RingError
from hal.config import RigConfig
from hal.rig_sections import FlightRecorderConfig, TimingConfig
from hal.errors import ConfigError

MAX_CONTROL_PER_CYCLE = 8
COMMAND_BUDGET_S = 250e-6  # the command stage's time for requests in a cycle, of 1 ms (docs/benchmarks.md)
MESSENGER_CHECK_CYCLES = 100  # how often the messenger process (the planner's and exchange workers) is looked at: 0.1 s
HELPER_CHECK_EVERY = 10  # the other helpers at every 10th of those looks: 1 s
RINGS_PREFIX = "pneumad-rings-"  # then the owning daemon's pid: <prefix><pid>-<random>
log = logging.getLogger("pneumad")
_TOPIC_TAG = {topic: tag for tag, topic in enumerate(TOPICS)}
# write(2) called with the GIL held (a PyDLL function keeps it): os.write lets the GIL go for
# the call, another thread of the daemon (the planner's courier, at the normal priority) can
# take it, and the loop then waits until that thread gives it back: 8-69 ms under a flood on a
# loaded machine, a stall trip. The doorbell pipe never blocks (O_NONBLOCK: a full pipe is
# EAGAIN, and the messenger has plenty to wake it then).
_WRITE = ctypes.PyDLL(None).write
_WRITE.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_size_t)
_WRITE.restype = ctypes.c_ssize_t


class ZmqServer:
    def __init__(self, command: str = DEFAULT_COMMAND, control: str = DEFAULT_CONTROL,
                 telemetry: str = DEFAULT_TELEMETRY, max_per_cycle: int = 2, loop_stall_s: float = STALL_S,
                 keys: str | None = None, insecure: bool = False, recording: dict | None = None,
                 plotjuggler: str | None = None, foxglove: str | None = None,
                 command_budget_s: float = COMMAND_BUDGET_S, timing: TimingConfig | None = None,
                 layout: CycleLayout | None = None, model: RigConfig | None = None):
        """``command_budget_s``: the time the command stage may spend on requests in a cycle
        (on the loop's clock: a virtual one never spends it). ``recording``: where and how the daemon records (``directory``, ``max_mb``,
        ``min_free_mb``, and ``flight``: the rig file's ``[flight_recorder]``, default its defaults), in a recorder
        process started at :meth:`attach`; None: it does not.
        ``plotjuggler``: an endpoint for PlotJuggler's rows (:mod:`daemon.messenger.plotjuggler`);
        ``foxglove``: HOST:PORT of the live Foxglove stream (:mod:`daemon.messenger.foxglove_stream`);
        ``timing``: the rig file's ``[timing]``, by which the messenger judges the loop's timing;
        ``layout``: the cycle record's (:func:`daemon.assembly.cycle_layout`), by which the
        messenger reads the state batches: the loop attached must have the same; ``model``: the
        rig whose model runs beside the arm (:mod:`daemon.model.process`, started at
        :meth:`attach` when its ``[model_watch]`` is enabled and it has a joint to watch)."""
        self.max_per_cycle = max_per_cycle
        self.command_budget_s = command_budget_s
        self.recording = recording
        self.recorder: RecorderProcess | None = None
        self._model_rig, self._model_joints = model, (wanted(model) if model is not None else [])
        self.model: ModelProcess | None = None
        self.security = security((command, control, telemetry), keys, insecure)
        if plotjuggler and not is_local(plotjuggler) and not insecure:
            raise ConfigError(f"--plotjuggler {plotjuggler}: PlotJuggler cannot use keys, so its endpoint must be "
                              f"local (tcp://127.0.0.1:PORT or ipc://; from a laptop, ssh -L PORT:127.0.0.1:PORT "
                              f"LAB-PC), or say --insecure")
        fox = foxglove_address(foxglove, insecure) if foxglove else None
        if layout is None:
            raise ValueError("a port needs the cycle record's layout (daemon.assembly.cycle_layout) for its messenger")
        self.layout = layout
        for name in reclaim_stale_rings(_shm_dir()):
            log.warning("removed the rings a killed daemon left behind: %s", name)
        self._rings_dir = tempfile.mkdtemp(prefix=f"{RINGS_PREFIX}{os.getpid()}-", dir=_shm_dir())
        self.rings = create_rings(self._rings_dir)
        self.heartbeat = Heartbeat(self._rings_dir, create=True)
        self.watchdog_link = WatchdogLink.create(self._rings_dir)  # the cycle watchdog's e-stops and reports
        self.stats_banks = StatsBanks.in_directory(self._rings_dir, create=True)  # the loop's histograms
        self._doorbell_read, self._doorbell = os.pipe()  # the read end stays open for a restarted messenger
        os.set_blocking(self._doorbell, False)
        self.messenger = Messenger(self._rings_dir, self._doorbell_read, command, control, telemetry, loop_stall_s,
                                   keys, recorder=recording is not None, plotjuggler=plotjuggler,
                                   foxglove=fox, timing=timing, layout=layout.describe(),
                                   flight=(recording.get("flight") or FlightRecorderConfig()) if recording else None,
                                   model=bool(self._model_joints))
        try:
            self.endpoints = self.messenger.start()
        except Exception:
            self._release_rings()
            raise
        self.commands: Commands | None = None
        self._waiting: list[tuple[int, Deferred]] = []  # (token, work) whose replies are owed
        self.reply_failures = 0
        self.telemetry_dropped = 0
        self._until_check = MESSENGER_CHECK_CYCLES
        self._helper_round = 0  # counts the messenger's looks up to the others'
        self._messenger_alive = True  # started above
        self._replied = False

    def attach(self, loop, preparer=None) -> None:
        """Serve ``loop``: its handlers on its named controls and handles (:mod:`daemon.loop.handles`)."""
        handles = loop.handles
        if handles.stats.banks is not self.stats_banks:
            raise ValueError("the loop counts its timing elsewhere: build it with this port's stats_banks")
        if handles.layout.id != self.layout.id:
            raise ValueError(f"the loop records on a layout other than its messenger's ({', '.join(handles.layout.names)}; "
                             f"the messenger's: {', '.join(self.layout.names)}): a transport whose outputs changed "
                             f"when it was opened")
        self._handles = handles
        self.commands = Commands(loop, preparer, self.security)
        self.commands.lease.carrier_down = self._messenger_down
        self.commands.port_health = lambda: {"telemetry": self.telemetry_health(), "helpers": self.helpers_health(),
                                             "model": self.model_status()}
        loop.server = self
        write_metadata(self._rings_dir, self.commands.described, self.commands.controller_get({}))
        if self.recording is not None:
            self.recorder = RecorderProcess(self._rings_dir, self.recording["directory"], self.recording["max_mb"],
                                            self.recording["min_free_mb"], self.recording.get("flight"))
            self.recorder.start()
        if self._model_joints:
            self.model = ModelProcess(self._rings_dir, self._model_rig, self._model_joints)
            self.model.start()

    def model_status(self) -> dict | None:
        """The status field ``model`` (:meth:`daemon.model.process.ModelProcess.status`); None
        when no model runs beside the arm."""
        return self.model.status() if self.model is not None else None

    def publish(self, topic: bytes, body: bytes | bytearray | memoryview) -> None:
        """Queue a telemetry message for the messenger (dropped and counted if the ring is full)."""
        if not self.rings["telemetry"].put(_TOPIC_TAG[topic], body):
            self.telemetry_dropped += 1

    def telemetry_health(self) -> dict:
        """As of the messenger's last look (every 0.1 s: a request that reaches the loop came
        through a messenger, so a status never waits on a process table)."""
        return {"messenger_running": self._messenger_alive, "messenger_restarts": self.messenger.restarts,
                "dropped": self.telemetry_dropped}

    def helpers_health(self) -> dict:
        """The status field ``helpers``: each process beside the loop as of its last look
        (running, pid, restarts, the last dead one's exit code)."""
        health = {"messenger": self.messenger.health()}
        if self.recorder is not None:
            health["recorder"] = self.recorder.health()
        if self.model is not None:
            health["model"] = self.model.health()
        if self.commands is not None:
            health["planner"] = self.commands.preparer.health()
            if self._handles.contact_sensor is not None:
                health["contact"] = self._handles.contact_sensor.health()
            worker = self._handles.transport.worker_health()
            if worker is not None:
                health["exchange"] = worker
        return health

    def poll(self, cycle: int) -> None:
        """Once a cycle (``cycle``: the loop's count), at its end: the lease clock, then the
        control requests, then a few commands; every 0.1 s the messenger process, the planner's
        worker and a transport's exchange worker, every second the other helpers. The heartbeat
        tells the messenger the loop is cycling."""
        clock = self._handles.clock
        until = clock.now() + self.command_budget_s
        self.heartbeat.beat(cycle)
        self.commands.tick()
        if self._waiting:
            self._complete()
        served = self._serve(self.rings["control"], True, MAX_CONTROL_PER_CYCLE, clock, until, 0)
        self._serve(self.rings["command"], False, self.max_per_cycle, clock, until, served)
        if self._replied:
            self._replied = False
            self._ring_doorbell()
        self._until_check -= 1
        if self._until_check <= 0:
            self._until_check = MESSENGER_CHECK_CYCLES
            self._look_after_helpers()

    def _look_after_helpers(self) -> None:
        """A helper that died is restarted (by its own handle, never waiting): the messenger, the
        planner's worker and an off-loop transport's exchange worker at every look, the recorder
        and the contact sensor's process at every HELPER_CHECK_EVERY-th; each restart is an
        event of the helper's kind, which the messenger logs as it publishes it."""
        events, contact = self._handles.events, self._handles.contact_sensor
        self._check_messenger()
        notice = self.commands.preparer.check()
        if notice is not None:
            events.add({"kind": "planner", "cause": notice})
        notice = self._handles.transport.check_worker()  # (at once: while it is dead, nothing writes to the rig)
        if notice is not None:
            events.add({"kind": "exchange", "cause": notice})
        self._helper_round = (self._helper_round + 1) % HELPER_CHECK_EVERY
        if self._helper_round:
            return
        notice = self.recorder.check() if self.recorder is not None else None
        if notice is not None:
            events.add({"kind": "recorder", "cause": notice})
        notice = contact.check() if contact is not None else None
        if notice is not None:
            events.add({"kind": "contact", "cause": notice})
        notice = self.model.check() if self.model is not None else None
        if notice is not None:
            events.add({"kind": "model", "action": "restarted", "cause": notice})

    def _check_messenger(self) -> None:
        """The messenger's look: a restart started, or finished (the lease's holder then has its
        ttl from now to renew), or announced (an event)."""
        was_down = self.messenger.down
        notice = self.messenger.check()
        self._messenger_alive = not self.messenger.down
        if was_down and not self.messenger.down:
            self.commands.lease.carried_again(self._handles.clock.now())
        if notice is not None:
            self._handles.events.add({"kind": "messenger", "cause": notice})

    def _messenger_down(self) -> bool:
        """For the lease, whose time ran out: is the messenger that carries its renewals down
        or restarting? Looked at once more now (a death since the last look is seen here)."""
        if not self.messenger.down:
            self._check_messenger()
        return self.messenger.down

    def _complete(self) -> None:
        """Reply to deferred commands whose work is done (applying it at this boundary)."""
        for item in [w for w in self._waiting if w[1].future.done()]:
            self._waiting.remove(item)
            self._reply(item[0], self.commands.complete(item[1]))

    def _serve(self, ring: Ring, control: bool, limit: int, clock, until: float, served: int) -> int:
        """Up to ``limit`` requests from ``ring`` while the cycle's budget lasts (``until`` on
        ``clock``; the cycle's first request whatever the budget): how many were served in the
        cycle, ``served`` before these included."""
        for _ in range(limit):
            if served and clock.now() >= until:
                return served
            try:
                entry = ring.get()
            except RingError as exc:  # only a bug or a stranger in the daemon's memory: stop the arm
                ring.discard()
                self.commands.loop.trip(f"{exc}; the requests queued in it were dropped")
                return served
            if entry is None:
                return served
            served += 1
            token, payload = entry
            try:
                client, request = routed.unpack(payload)
            except Exception:  # only the messenger writes these (msgpack raises several types): a bug, answered as one
                self._reply(token, P.encode_error(None, P.INTERNAL, "the request reached the loop without its "
                                                                    "envelope or who sent it"))
                continue
            reply = self.commands.handle_request(request, control, client)
            if isinstance(reply, Deferred):
                self._waiting.append((token, reply))
            else:
                self._reply(token, reply)
        return served

    def _reply(self, token: int, reply: bytes) -> None:
        if self.rings["replies"].put(token, reply):
            self._replied = True
        else:
            self.reply_failures += 1  # the messenger is not taking replies: the client's time-out tells it

    def _ring_doorbell(self) -> None:
        _WRITE(self._doorbell, b"\0", 1)  # with the GIL held (_WRITE); a full pipe (-1, EAGAIN) wakes it already

    def close(self) -> None:
        """Stop the preparer (one of its own), then the messenger once it has passed on what
        the loop sent."""
        if self.commands is not None and self.commands.owns_preparer:
            self.commands.preparer.close()
        self.rings["telemetry"].put(END, b"")
        self.messenger.join()
        if self.recorder is not None:
            self.recorder.join()  # the messenger's END reached it: it finishes its files
        if self.model is not None:
            self.model.join()  # (the END reached it too)
        self._release_rings()

    def _release_rings(self) -> None:
        for ring in self.rings.values():
            ring.close()
        self.heartbeat.close()
        self.watchdog_link.close()
        os.close(self._doorbell)
        os.close(self._doorbell_read)
        shutil.rmtree(self._rings_dir, ignore_errors=True)


def reclaim_stale_rings(directory: str | None) -> list[str]:
    """Remove the rings a daemon killed outright (SIGKILL, a power cut of its process) left
    behind: directories named for a process that no longer exists. What was removed."""
    directory = directory or tempfile.gettempdir()
    removed = []
    for name in os.listdir(directory):
        pid, sep, _ = name[len(RINGS_PREFIX):].partition("-")
        if name.startswith(RINGS_PREFIX) and sep and pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(os.path.join(directory, name), ignore_errors=True)
            removed.append(name)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's process
    return True


def _shm_dir() -> str | None:
    """RAM-backed /dev/shm where there is one (the rings never touch a disk), else the default."""
    return "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None


LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]", "lo")


def is_local(endpoint: str) -> bool:
    """Whether only this machine can reach ``endpoint``: ipc, inproc, or tcp on loopback."""
    scheme, _, address = endpoint.partition("://")
    if scheme in ("ipc", "inproc"):
        return True
    host = address.rpartition(":")[0]
    return scheme == "tcp" and (host in LOCAL_HOSTS or host.startswith("127."))


def foxglove_address(address: str, insecure: bool) -> tuple[str, int]:
    """``--foxglove HOST:PORT`` as (host, port): loopback unless ``insecure`` (the Foxglove
    protocol has no CURVE: anyone who reaches the port sees the arm), else a ConfigError."""
    host, _, port = address.rpartition(":")
    host = host.strip("[]")
    if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ConfigError(f"--foxglove {address}: give HOST:PORT, e.g. 127.0.0.1:8765")
    if not insecure and not (host in LOCAL_HOSTS or host.startswith("127.")):
        raise ConfigError(f"--foxglove {address}: the Foxglove protocol cannot use keys, so it must listen on loopback "
                          f"(127.0.0.1:PORT; from a laptop, ssh -L {port}:127.0.0.1:{port} LAB-PC and connect Foxglove "
                          f"to ws://localhost:{port}), or say --insecure")
    return host, int(port)


def security(endpoints, keys: str | None, insecure: bool) -> dict:
    """What the endpoints and keys add up to (``describe`` and ``status`` say it): "curve"
    (every client's key checked), "local" (no keys, loopback only) or "insecure" (no keys past
    loopback, only with ``insecure``: refused otherwise, a ConfigError)."""
    if keys:
        return {"mode": "curve", "warning": None}
    exposed = [ep for ep in endpoints if not is_local(ep)]
    if not exposed:
        return {"mode": "local", "warning": None}
    if not insecure:
        raise ConfigError(f"{exposed[0]} is reachable from the network, and without keys anyone who reaches it can "
                          f"take the lease and move the arm: give the daemon its keys (--keys DIR; make them with "
                          f"`pneumad keys init`), or bind loopback, or say --insecure if this network is yours alone")
    return {"mode": "insecure", "warning": f"no authentication: anyone who can reach {', '.join(exposed)} can take "
                                           f"the lease and move the arm (started with --insecure)"}
