"""The recorder process's work (:mod:`daemon.recorder.process`): the daemon's recordings in progress,
the requests that start, stop and list them, and the telemetry they are written from.

Every recording is an MCAP file (:class:`daemon.recordings.mcap_log.McapRecording`) in the recording
directory. A recording ends by request, after its ``seconds`` or ``TAIL_S`` after the end of
the reference it follows (both on the daemon's clock, by the samples written: a recorder behind
its feed still records all of them), at its size limit, when the disk's free space falls below the
floor, or at a write error; each end is a ``record`` event saying why. A recording starts with
the last half second of the state stream (``PREROLL_BATCHES``): what led up to its start, and
says in its metadata how long it is meant to run (a reader of a cut one says how much is missing).

A file is whole, or finished up to its last complete chunk by
:func:`daemon.recordings.mcap_repair.repair`, so every MCAP reader opens it: at once where its
own finish failed (a write error, a full disk), and, for a recorder that died while writing
(killed, or its daemon was), by the next recorder to start on the directory, before it serves
anything. It knows those files by their markers (``.NAME.mcap.writing``, there while a recording
runs) and leaves alone one whose writer still holds its lock (another daemon's recorder).

Beside the recordings, the flight recorder (:mod:`daemon.recorder.flight`) holds the last seconds
of every topic and writes them, into the same directory, for each trip, e-stop and stalled loop
and on ``record.snapshot``.
"""
from __future__ import annotations

import fcntl
import json
import logging
import os
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import msgpack

from daemon.wire import catalog
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed
from daemon.wire.flight import PREFIX as FLIGHT_PREFIX
from daemon.recordings.mcap_log import McapRecording, TelemetryEncoder
from daemon.recordings.mcap_repair import repair
from daemon.recorder.flight import FlightRecorder
from hal.rig_sections import FlightRecorderConfig

TAIL_S = 3.0  # a reference's recording runs on this long after its end: the settling (a step's response)
MAX_ACTIVE = 4
LIST_LIMIT = 100  # files record.list shows, newest first
PREROLL_BATCHES = 50  # state batches (10 cycles each) a new recording starts with: 0.5 s before its start
DISK_CHECK_S = 1.0
FEED_LOST_S = 5.0  # a timed recording whose feed stopped this long ends by the recorder's clock
MARKER = ".writing"  # .NAME.mcap.writing: a recording is being written into NAME.mcap
log = logging.getLogger("pneumad")
LEFT_CAUSE = "its recorder died before it finished the file: killed, or its daemon was"


@dataclass
class Active:
    """A recording in progress."""

    name: str
    path: str
    file: object
    writer: McapRecording
    who: str
    started: float  # [s] monotonic
    t0: float | None = None  # [s] the daemon's clock at its start (the feed's last sample, or its next one)
    seconds: float | None = None  # record.start's seconds: its length on the daemon's clock (None: until stopped)
    reference: int | None = None  # the reference generation it follows
    until_t: float = float("inf")  # [s] on the daemon's clock: it ends with the state sample of this
    # time, however far behind the feed the recorder is (a loaded PC): t0 + seconds, or a reference's end
    stats: dict = field(default_factory=dict)

    def summary(self, feed_t: float | None) -> dict:
        """``seconds``: recorded so far, and ``ends_in_s``, both on the daemon's clock (by the samples
        taken in; before the first, none recorded)."""
        try:
            size = self.file.tell()
        except (OSError, ValueError):
            size = None
        by_feed = self.t0 is not None and feed_t is not None
        so_far = feed_t - self.t0 if by_feed else 0.0
        ends_in = None if self.seconds is None else max(self.until_t - feed_t, 0.0) if by_feed else self.seconds
        return {"name": self.name, "file": self.path, "who": self.who, "seconds": so_far,
                "messages": self.writer.messages, "gaps": self.writer.gaps, "bytes": size,
                "follows_reference": self.reference is not None, "ends_in_s": ends_in}


class Archive:
    def __init__(self, rings_dir: str, directory: str, max_bytes: float, min_free_bytes: float,
                 emit: Callable[[dict], None], flight: FlightRecorderConfig | None = None):
        self.rings_dir, self.directory = rings_dir, os.path.abspath(directory)
        self.max_bytes, self.min_free_bytes = max_bytes, min_free_bytes
        self.emit = emit
        self.active: dict[str, Active] = {}
        with open(os.path.join(rings_dir, "describe.json")) as f:
            self.describe = json.load(f)
        with open(os.path.join(rings_dir, "controller.json")) as f:
            self.controller = json.load(f)
        self.encoder = TelemetryEncoder(self.describe)  # one encoding of each message for every recording
        self._disk_checked = 0.0
        # the last seconds of every topic, written on each trip (daemon.recorder.flight)
        self.flight = FlightRecorder(flight or FlightRecorderConfig(), self._open_file, self._file_done,
                                     lambda: (self.describe, self.controller), self._tell)
        self._handlers = {"record.start": self._start_request, "record.stop": self._stop_request, "record.list": self._list,
                          "record.snapshot": self._snapshot_request}
        catalog.check_handlers(("recorder",), self._handlers)
        self._preroll: deque[dict] = deque(maxlen=PREROLL_BATCHES)
        self.feed_t: float | None = None  # [s] the daemon's clock at the last state sample taken in (record.list)
        self.behind_s: float | None = None  # [s] roughly how far behind the daemon the feed still was when
        #                                     the requests came (the process's catch-up); None: caught up
        self._fed_at = time.monotonic()  # [s] when it came (or the recorder started: a feed that is
        #                                  late to begin is not one that stopped)

    def _tell(self, event: dict) -> None:
        """An event (through the messenger); one a recording failed or was finished after its
        writer died by is the daemon's log's too."""
        if event.get("action") in ("failed", "repaired"):
            log.warning("recording %s %s: %s", event.get("file", event.get("name")), event["action"], event.get("cause"))
        self.emit(event)

    # -- requests (from the messenger) -----------------------------------------------------
    def request(self, body: bytes, who: str) -> bytes:
        """Answer one ``record.*`` request (already allowed by the messenger): the reply's bytes."""
        try:
            request = P.decode_request(body)
        except P.ProtocolError as exc:
            return P.encode_error(exc.request_id, exc.code, exc.message)
        handler = self._handlers.get(request["cmd"])
        if handler is None:  # the messenger routes only the recorder's commands here: a bug, answered as one
            return P.encode_error(request["id"], P.INTERNAL, f"the recorder serves no {request['cmd'][:80]!r}")
        try:
            return P.encode_result(request["id"], handler(P.decode_args(request), who))
        except CommandFailed as exc:
            return P.encode_error(request["id"], exc.code, str(exc), exc.data)
        except P.ProtocolError as exc:
            return P.encode_error(request["id"], exc.code, exc.message)

    def _start_request(self, args: dict, who: str) -> dict:
        name = args.get("name")
        if name is not None:  # the messenger checked it (the catalog's): checked again where it becomes a file name
            catalog.COMMANDS["record.start"].arg("name").check(name)
        seconds = args.get("seconds")
        active = self.start(name or f"{time.strftime('%Y%m%d-%H%M%S')}-record", who, seconds)
        return active.summary(self.feed_t)

    def _stop_request(self, args: dict, who: str) -> dict:
        name = args.get("name")
        if name is None:  # the one started by request (those following a reference end with it)
            started = [a.name for a in self.active.values() if a.reference is None]
            if len(started) != 1:
                raise CommandFailed(P.BAD_STATE, "no recording started by record.start is running" if not started else
                                    f"{len(started)} recordings are running: name one of {', '.join(sorted(started))}",
                                    {"reason": "recording"})
            name = started[0]
        if name not in self.active:
            raise CommandFailed(P.BAD_STATE, f"no recording named {str(name)[:80]!r} is running", {"reason": "recording"})
        cause = f"record.stop from {who}"
        if self.behind_s is not None:  # a loaded PC: the file ends where the recorder got to, and says so
            cause += (f"; the recorder had not caught up with the daemon's telemetry: the file ends about "
                      f"{self.behind_s:.2f} s before the stop")
        return self.end(self.active[name], cause)

    def _snapshot_request(self, args: dict, who: str) -> dict:
        name = args.get("name")
        if name is not None:  # the messenger checked it (the catalog's): checked again where it becomes a file name
            catalog.COMMANDS["record.snapshot"].arg("name").check(name)
        return self.flight.snapshot(name or f"{FLIGHT_PREFIX}{time.strftime('%Y%m%d-%H%M%S')}-snapshot", who, self.feed_t)

    def _list(self, args: dict, who: str) -> dict:
        try:
            entries = [e for e in os.scandir(self.directory) if e.name.endswith(".mcap") and e.is_file()]
        except OSError:
            entries = []
        entries.sort(key=lambda e: e.stat().st_mtime, reverse=True)
        return {"directory": self.directory, "feed_t": self.feed_t,
                "active": [a.summary(self.feed_t) for a in self.active.values()],
                "files": [{"name": e.name[:-5], "bytes": e.stat().st_size, "modified_unix_s": e.stat().st_mtime}
                          for e in entries[:LIST_LIMIT]], "more": max(len(entries) - LIST_LIMIT, 0),
                "flight": self.flight.summary()}

    # -- recordings ------------------------------------------------------------------------
    def _path(self, name: str) -> str:
        return os.path.join(self.directory, name + ".mcap")

    def _marker(self, path: str) -> str:
        return os.path.join(self.directory, "." + os.path.basename(path) + MARKER)

    def finish_left_files(self) -> None:
        """Finish the files recorders that died left in the directory (their markers), each with
        a ``record`` event (``repaired``, or ``failed`` with why not); those another daemon's
        recorder is writing (it holds their lock) are left alone."""
        try:
            markers = [e.name for e in os.scandir(self.directory) if e.name.startswith(".") and e.name.endswith(MARKER)]
        except OSError:
            return
        for marker in markers:
            path = os.path.join(self.directory, marker[1:-len(MARKER)])
            event = {"kind": "record", "name": os.path.basename(path)[:-len(".mcap")], "file": path}
            try:
                with open(path, "rb") as f:
                    fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)  # BlockingIOError: being written
                    repaired = repair(path, LEFT_CAUSE)
                if repaired is not None:
                    self._tell({**event, "action": "repaired", "cause": LEFT_CAUSE, "messages": repaired.messages,
                               "bytes": os.path.getsize(path)})
            except BlockingIOError:
                continue
            except FileNotFoundError:
                pass
            except (OSError, ValueError) as exc:
                self._tell({**event, "action": "failed", "cause": f"{LEFT_CAUSE}; it could not be finished: "
                                                                 f"{getattr(exc, 'strerror', None) or exc}"})
            try:
                os.remove(os.path.join(self.directory, marker))
            except OSError:
                pass

    def start(self, name: str, who: str, seconds: float | None = None, reference: int | None = None,
              ends_t: float | None = None) -> Active:
        """Open a new recording (a taken name gets a -2, -3 ... suffix), ``seconds`` [s] long on the
        daemon's clock from the last sample taken in when its file is open, or the first to come
        (None: until stopped; ``ends_t``: a reference's recording's planned end on the daemon's
        clock); CommandFailed if it cannot be."""
        if len(self.active) >= MAX_ACTIVE:
            raise CommandFailed(P.BAD_STATE, f"{MAX_ACTIVE} recordings are running already: stop one first",
                                {"reason": "recording"})
        try:
            f, path = self._open_file(name)
            name = os.path.basename(path)[:-len(".mcap")]
            plan = {} if ends_t is None else {"planned_end_t": ends_t}
            if seconds is not None:
                plan = {"planned_s": seconds, **({"planned_end_t": self.feed_t + seconds} if self.feed_t is not None else {})}
            try:
                writer = McapRecording(f, self.describe, self.controller, self.encoder, plan)
            except OSError:
                f.close()
                raise
        except OSError as exc:
            raise CommandFailed(P.BAD_STATE, f"cannot record to {self.directory}: {exc.strerror or exc}",
                                {"reason": "recording"}) from None
        started = time.monotonic()
        active = Active(name, self._path(name), f, writer, who, started, self.feed_t, seconds, reference)
        if seconds is not None and self.feed_t is not None:
            active.until_t = self.feed_t + seconds  # (else from the first sample to come: message())
        for message in self._preroll:  # what led up to it
            writer.write("state", message)
        self.active[name] = active
        self._tell({"kind": "record", "action": "start", "name": name, "file": active.path, "who": who,
                   "follows_reference": reference is not None})
        return active

    def _open_file(self, name: str):
        """A new file NAME.mcap (a taken name gets a -2, -3 ... suffix), locked and marked as being
        written (finish_left_files); the open file and its path. OSError if it cannot be."""
        os.makedirs(self.directory, exist_ok=True)
        self._check_free_space()
        base, n = name, 1
        while True:
            try:
                f = open(self._path(name), "xb")
                break
            except FileExistsError:
                n += 1
                name = f"{base}-{n}"
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)  # held while it is written: finish_left_files
            open(self._marker(self._path(name)), "w").close()
        except OSError:
            f.close()
            raise
        return f, self._path(name)

    def _file_done(self, path: str) -> None:
        try:
            os.remove(self._marker(path))
        except OSError:
            pass

    def end(self, active: Active, cause: str, failed: bool = False, write_error: bool = False) -> dict:
        """Close a recording; its summary (also an event). After a ``write_error`` (a record may
        be half written) it is not finished as usual but cut at its last complete chunk."""
        self.active.pop(active.name, None)
        summary = active.summary(self.feed_t)
        unfinished = cause if write_error else None
        try:
            if not write_error:
                active.writer.finish()
        except (OSError, ValueError) as exc:
            failed, unfinished = True, f"{cause}; the file's index could not be written ({exc})"
        finally:
            try:
                active.file.close()
            except (OSError, ValueError):
                pass
        if unfinished is not None:
            cause = unfinished
            try:
                repair(active.path, unfinished)
                cause += ": finished up to its last complete chunk"
            except (OSError, ValueError) as exc:
                cause += f", nor could it be finished ({getattr(exc, 'strerror', None) or exc}): pneumactl export, " \
                         f"plot and recordings.load read it up to its last complete chunk"
        self._file_done(active.path)
        try:
            summary["bytes"] = os.path.getsize(active.path)
        except OSError:
            pass
        summary["cause"] = cause
        self._tell({"kind": "record", "action": "failed" if failed else "stop", **summary})
        return summary

    def close(self, cause: str) -> None:
        for active in list(self.active.values()):
            self.end(active, cause)
        self.flight.close()

    # -- telemetry --------------------------------------------------------------------------
    def message(self, topic: str, body: bytes) -> None:
        """One telemetry message as subscribers receive it: kept up to date with, written to
        every recording in progress."""
        try:
            message = msgpack.unpackb(body, raw=False)
        except Exception:
            return  # only the messenger sends these
        last_t = message["t"][-1] if topic == "state" and message.get("t") else None
        self.flight.take(topic, body, last_t if last_t is not None else self.feed_t)
        if topic == "event":
            self._follow(message)
            self.flight.event(message)
        elif topic == "state":
            self._preroll.append(message)
            if last_t is not None:
                self.feed_t, self._fed_at = last_t, time.monotonic()
                for active in self.active.values():
                    if active.t0 is None and active.seconds is not None:  # started before any sample came
                        active.t0, active.until_t = message["t"][0], message["t"][0] + active.seconds
        if not self.active and topic != "event":  # (events: the encoder follows a reference's phase)
            return
        encoded = self.encoder.encode(topic, message)
        for active in list(self.active.values()):
            try:
                active.writer.write(topic, message, encoded=encoded)
                if active.file.tell() >= self.max_bytes:
                    self.end(active, f"it reached the size limit ({self.max_bytes / 1e6:.0f} MB)")
                elif last_t is not None and last_t >= active.until_t:
                    self.end(active, "its reference ended" if active.reference is not None else "its time was up")
            except (OSError, ValueError) as exc:
                self.end(active, f"write error: {getattr(exc, 'strerror', None) or exc}", failed=True, write_error=True)

    def _follow(self, event: dict) -> None:
        """What events tell the recorder: the controller in force, and the references it records."""
        kind = event.get("kind")
        if kind in ("controller", "params"):
            self.controller = {"name": event.get("to", event.get("controller")), "params": event.get("params"),
                               "source": event.get("source")}  # a plugin file's path and hash, None for others
            try:
                with open(os.path.join(self.rings_dir, "controller.json"), "w") as f:
                    json.dump(self.controller, f)  # for a recorder started again
            except OSError:
                pass
        elif kind == "reference" and event.get("action") == "start" and event.get("record"):
            try:
                ends = float(event.get("t", 0.0)) + float(event.get("duration_s") or 0.0) + TAIL_S
                active = self.start(str(event["record"]), str(event.get("who", "")), None, event.get("generation"), ends)
                # ended by the reference's end event; at the latest 10 s past its planned end
                active.until_t = ends + 10.0
            except CommandFailed as exc:
                self._tell({"kind": "record", "action": "failed", "name": event["record"], "cause": str(exc)})
        elif kind == "reference" and event.get("action") == "end" or kind == "state" and event.get("to") != "enabled":
            for active in self.active.values():
                if active.reference is not None and (kind == "state" or active.reference == event.get("generation")):
                    active.until_t = min(active.until_t, float(event.get("t", 0.0)) + TAIL_S)

    def tick(self, now: float) -> None:
        """Recordings whose time is up end; every second, the disk's free space is checked."""
        if now - self._fed_at >= FEED_LOST_S:  # no samples to end it by: its length on the recorder's clock
            for active in [a for a in self.active.values() if a.seconds is not None and now - a.started >= a.seconds]:
                self.end(active, f"its time was up (no telemetry from the daemon for {FEED_LOST_S:g} s or more)")
        if self.active and now - self._disk_checked >= DISK_CHECK_S:
            self._disk_checked = now
            try:
                self._check_free_space()
            except OSError as exc:
                for active in list(self.active.values()):
                    self.end(active, exc.strerror or str(exc), failed=True)

    def _check_free_space(self) -> None:
        st = os.statvfs(self.directory)
        free = st.f_bavail * st.f_frsize
        if free < self.min_free_bytes:
            raise OSError(28, f"the disk is nearly full: {free / 1e6:.0f} MB left (the floor is "
                              f"{self.min_free_bytes / 1e6:.0f} MB)")
