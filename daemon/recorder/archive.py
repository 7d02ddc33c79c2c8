"""The recorder process's work (:mod:`daemon.recorder.process`): the daemon's recordings in progress,
the requests that start, stop and list them, and the telemetry they are written from.

Every recording is an MCAP file (:class:`daemon.recordings.mcap_log.McapRecording`) in the recording
directory. A recording ends by request, after its ``seconds`` or ``TAIL_S`` after the end of
the reference it follows (both on the daemon's clock, by the samples written: a recorder behind
its feed still records all of them), at its size limit, when the disk's free space falls below the
floor, or at a write error; each end is a ``record`` event saying why, and the file is
readable up to its last complete chunk whatever the cause. A recording starts with the last
half second of the state stream (``PREROLL_BATCHES``): what led up to its start.
"""
from __future__ import annotations

import json
import os
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import msgpack

from daemon.wire import catalog
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed
from daemon.recordings.mcap_log import McapRecording, TelemetryEncoder

TAIL_S = 3.0  # a reference's recording runs on this long after its end: the settling (a step's response)
MAX_ACTIVE = 4
LIST_LIMIT = 100  # files record.list shows, newest first
PREROLL_BATCHES = 50  # state batches (10 cycles each) a new recording starts with: 0.5 s before its start
DISK_CHECK_S = 1.0
FEED_LOST_S = 5.0  # a timed recording whose feed stopped this long ends by the recorder's clock


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
                 emit: Callable[[dict], None]):
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
        self._handlers = {"record.start": self._start_request, "record.stop": self._stop_request, "record.list": self._list}
        catalog.check_handlers(("recorder",), self._handlers)
        self._preroll: deque[dict] = deque(maxlen=PREROLL_BATCHES)
        self.feed_t: float | None = None  # [s] the daemon's clock at the last state sample taken in (record.list)
        self.behind_s: float | None = None  # [s] roughly how far behind the daemon the feed still was when
        #                                     the requests came (the process's catch-up); None: caught up
        self._fed_at = time.monotonic()  # [s] when it came (or the recorder started: a feed that is
        #                                  late to begin is not one that stopped)

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

    def _list(self, args: dict, who: str) -> dict:
        try:
            entries = [e for e in os.scandir(self.directory) if e.name.endswith(".mcap") and e.is_file()]
        except OSError:
            entries = []
        entries.sort(key=lambda e: e.stat().st_mtime, reverse=True)
        return {"directory": self.directory, "feed_t": self.feed_t,
                "active": [a.summary(self.feed_t) for a in self.active.values()],
                "files": [{"name": e.name[:-5], "bytes": e.stat().st_size, "modified_unix_s": e.stat().st_mtime}
                          for e in entries[:LIST_LIMIT]], "more": max(len(entries) - LIST_LIMIT, 0)}

    # -- recordings ------------------------------------------------------------------------
    def _path(self, name: str) -> str:
        return os.path.join(self.directory, name + ".mcap")

    def start(self, name: str, who: str, seconds: float | None = None, reference: int | None = None) -> Active:
        """Open a new recording (a taken name gets a -2, -3 ... suffix), ``seconds`` [s] long on the
        daemon's clock from the last sample taken in when its file is open, or the first to come
        (None: until stopped); CommandFailed if it cannot be."""
        if len(self.active) >= MAX_ACTIVE:
            raise CommandFailed(P.BAD_STATE, f"{MAX_ACTIVE} recordings are running already: stop one first",
                                {"reason": "recording"})
        try:
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
            writer = McapRecording(f, self.describe, self.controller, self.encoder)
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
        self.emit({"kind": "record", "action": "start", "name": name, "file": active.path, "who": who,
                   "follows_reference": reference is not None})
        return active

    def end(self, active: Active, cause: str, failed: bool = False) -> dict:
        """Close a recording; its summary (also an event)."""
        self.active.pop(active.name, None)
        summary = active.summary(self.feed_t)
        try:
            active.writer.finish()
        except (OSError, ValueError) as exc:
            failed, cause = True, f"{cause}; the file's index could not be written ({exc}): readable up to its last chunk"
        finally:
            try:
                active.file.close()
            except OSError:
                pass
        try:
            summary["bytes"] = os.path.getsize(active.path)
        except OSError:
            pass
        summary["cause"] = cause
        self.emit({"kind": "record", "action": "failed" if failed else "stop", **summary})
        return summary

    def close(self, cause: str) -> None:
        for active in list(self.active.values()):
            self.end(active, cause)

    # -- telemetry --------------------------------------------------------------------------
    def message(self, topic: str, body: bytes) -> None:
        """One telemetry message as subscribers receive it: kept up to date with, written to
        every recording in progress."""
        try:
            message = msgpack.unpackb(body, raw=False)
        except Exception:
            return  # only the messenger sends these
        last_t = message["t"][-1] if topic == "state" and message.get("t") else None
        if topic == "event":
            self._follow(message)
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
                self.end(active, f"write error: {getattr(exc, 'strerror', None) or exc}", failed=True)

    def _follow(self, event: dict) -> None:
        """What events tell the recorder: the controller in force, and the references it records."""
        kind = event.get("kind")
        if kind in ("controller", "params"):
            self.controller = {"name": event.get("to", event.get("controller")), "params": event.get("params")}
            try:
                with open(os.path.join(self.rings_dir, "controller.json"), "w") as f:
                    json.dump(self.controller, f)  # for a recorder started again
            except OSError:
                pass
        elif kind == "reference" and event.get("action") == "start" and event.get("record"):
            try:
                active = self.start(str(event["record"]), str(event.get("who", "")), None, event.get("generation"))
                # ended by the reference's end event; at the latest 10 s past its planned end
                active.until_t = float(event.get("t", 0.0)) + float(event.get("duration_s") or 0.0) + TAIL_S + 10.0
            except CommandFailed as exc:
                self.emit({"kind": "record", "action": "failed", "name": event["record"], "cause": str(exc)})
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
