"""The recorder: the daemon's own recordings, written in a process of their own beside the loop.

The messenger hands it every telemetry message as it leaves the loop's ring (a ZeroMQ PUSH
on a private ipc socket in the rings' directory, before any network; the messenger binds it and
this process connects, so its queue keeps its order across a messenger's restart), so a recording never
loses what a slow or stalled client would; what it does lose (its own queue full, a write
slower than the telemetry) shows as a ``gap`` in the file, from the topics' ``seq``. It
writes MCAP (:mod:`daemon.recordings.mcap_log`) into the daemon's recording directory.

Recordings start and stop by request (``record.start``, ``record.stop``, ``record.list``,
which the messenger passes here and never to the loop), or follow a reference: a motion
command with ``record: true`` has its ``reference`` start event name a recording, which runs
from that event to ``archive.TAIL_S`` after the reference's end (or its cut, or the arm leaving
``enabled``). A write error or a full disk (less than ``min_free_mb`` left) ends a recording
with an event, the file finished up to its last complete chunk; the loop never knows. Once
started (a daemon's start, or again after a recorder died), it first finishes the files a dead
recorder left (:meth:`daemon.recorder.archive.Archive.finish_left_files`). Its events wait
(``EVENTS_HELD``) until the messenger is connected: a recorder just started has none yet.
Between them it writes the flight recorder's files (:mod:`daemon.recorder.flight`), a slice of
``BATCH_S`` at a time.

The metadata of a recording (``describe``, the controller and its parameters) come from the
files the daemon writes into the rings' directory at start (``describe.json``,
``controller.json``), kept up to date from the ``controller`` and ``params`` events.

It is a helper process (:class:`hal.process.Helper`) at nice 5; when the daemon dies it gets
SIGTERM, and finishes its files.
"""
from __future__ import annotations

import json
import logging
import os
import signal
import time

from hal.rig_sections import FlightRecorderConfig
from hal.process import Child, Helper, HelperFailed
from daemon.wire.helper_links import (EVENT, MARK, MESSENGER_ID, RECORDER_CONTROL, RECORDER_FEED, RECORDER_FEED_HWM,
                                      REPLY, endpoint)

BATCH_S = 0.02  # [s] of writing at most between two looks at the requests: a reply waits no longer
FEED_EVERY_MS = 50  # the feed is read this often, not at every message: 20 wake-ups a second, not ~110
CATCH_UP_S = 1.0  # [s] of taking in the feed at most before requests are answered (the client waits 2 s)
EVENTS_HELD = 100  # events kept while no messenger is connected (a recorder just started, a messenger restarting)


class RecorderProcess:
    """The daemon's handle on the recorder process (started, restarted if it dies, joined)."""

    def __init__(self, rings_dir: str, directory: str, max_mb: float, min_free_mb: float,
                 flight: FlightRecorderConfig | None = None):
        self.rings_dir, self.directory = rings_dir, directory
        self._proc = Helper("daemon.recorder.process:serve", (rings_dir, directory, max_mb, min_free_mb, flight),
                            name="the recorder", death_signal=signal.SIGTERM, ignore=(signal.SIGINT,), nice=5)

    @property
    def restarts(self) -> int:
        return self._proc.restarts

    def start(self) -> None:
        self._proc.start()  # HelperFailed, in its words, if it did not start

    def check(self) -> str | None:
        """Called once a second from the loop, never blocking: a dead recorder is started again
        (its recordings in progress end where they were); what happened, as an event's cause."""
        code = self._proc.restart_if_dead()
        if code is None:
            try:
                self._proc.poll_ready()  # (health: running once the new one is)
            except HelperFailed:
                pass  # it exits: the next check starts another
            return None
        return f"the recorder process exited (code {code}) and was restarted (restart {self.restarts}); " \
               f"its recordings in progress end where they were"

    def health(self) -> dict:
        return self._proc.health()

    @property
    def alive(self) -> bool:
        return self._proc.alive

    def join(self, timeout: float = 5.0) -> None:
        """Wait for the process to finish its files once the messenger has ended the feed
        (then SIGTERM, which finishes them too, then SIGKILL)."""
        self._proc.join(timeout, terminate_first=True)


def write_metadata(rings_dir: str, describe: dict, controller: dict) -> None:
    """The daemon's ``describe`` and its controller at start, for the recorder (start-up only)."""
    for name, doc in (("describe.json", describe), ("controller.json", controller)):
        with open(os.path.join(rings_dir, name), "w") as f:
            json.dump(doc, f)


# -- in the recorder process ----------------------------------------------------------------
def serve(child: Child, rings_dir: str, directory: str, max_mb: float, min_free_mb: float,
          flight: FlightRecorderConfig | None = None) -> int:
    """The recorder process's main: bind its sockets, say ready, record until the feed's end,
    SIGTERM or the parent's end."""
    import zmq

    from daemon.recorder.archive import Archive
    logging.basicConfig(level=logging.INFO, format="pneumad recorder %(levelname)s: %(message)s")  # the daemon's log
    stop = []  # SIGINT is ignored: the daemon ends the feed when it stops
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a file-size limit is a write error, not death
    ctx = zmq.Context()
    feed, control = ctx.socket(zmq.PULL), ctx.socket(zmq.ROUTER)
    feed.setsockopt(zmq.RCVHWM, RECORDER_FEED_HWM)
    control.setsockopt(zmq.ROUTER_HANDOVER, 1)  # a restarted messenger takes its id over
    control.setsockopt(zmq.ROUTER_MANDATORY, 1)  # a send with no messenger connected fails (held, not lost)
    for sock in (feed, control):
        sock.setsockopt(zmq.LINGER, 0)
    feed.connect(endpoint(rings_dir, RECORDER_FEED))  # the messenger's: one queue, in order, across its restarts
    control.bind(endpoint(rings_dir, RECORDER_CONTROL))
    held: list[list[bytes]] = []  # events no messenger has taken yet
    archive = Archive(rings_dir, directory, max_mb * 1e6, min_free_mb * 1e6,
                      lambda event: _send_event(control, held, json.dumps(event).encode()), flight)
    child.ready()
    archive.finish_left_files()
    poller = zmq.Poller()  # requests wake it at once; the feed waits in its queue, read in batches
    poller.register(control, zmq.POLLIN)
    behind = False
    while not stop and child.parent_alive():
        if held:
            _send_held(control, held)
        ready = dict(poller.poll(0 if behind else FEED_EVERY_MS))
        if control not in ready:
            behind = _take_feed(feed, archive, stop)
        else:
            requests = []
            while True:
                try:
                    frames = control.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                if len(frames) == 4:  # [routing id, token, who, request]
                    requests.append(frames)
            # first everything published before them: up to the last one's mark in the feed
            archive.behind_s = _catch_up(feed, archive, stop, requests[-1][1]) if requests else None
            behind = archive.behind_s is not None
            for _, token, who, body in requests:
                _send(control, [REPLY, token, archive.request(body, who.decode(errors="replace"))])
        archive.tick(time.monotonic())
        writing = archive.flight.work(archive.feed_t, BATCH_S)  # a flight file, a slice at a time
        behind = behind or writing
    archive.close("the daemon stopped")
    feed.close()
    control.close()
    ctx.term()
    return 0


def _take_one(feed, archive, stop: list) -> tuple[bytes, bytes] | None:
    """One message off the feed, taken in (telemetry to the archive; the loop's END, an empty
    topic, sets ``stop``; a request's mark is only returned): its (topic, body), None if none
    was waiting."""
    import zmq
    try:
        topic, body = feed.recv_multipart(zmq.NOBLOCK)
    except (zmq.Again, ValueError):
        return None
    if not topic:  # the messenger passed on the loop's END
        stop.append(1)
    elif topic != MARK:
        archive.message(topic.decode(), body)
    return topic, body


def _take_feed(feed, archive, stop: list) -> bool:
    """The telemetry queued in the feed, at most BATCH_S of writing (then the requests again,
    however far behind the feed is); True if some was left for the next round."""
    batch_ends = time.monotonic() + BATCH_S
    for _ in range(1000):
        if time.monotonic() > batch_ends:
            return True
        taken = _take_one(feed, archive, stop)
        if taken is None or not taken[0]:  # (a mark that came before its request: passed)
            return False
    return True


def _catch_up(feed, archive, stop: list, token: bytes) -> float | None:
    """Before requests: take in the telemetry published before them, up to the last request's
    mark (the messenger puts it on the feed just before the request: one socket keeps the
    order two do not), for at most CATCH_UP_S. None once there; else roughly how far behind
    the daemon [s] the feed still is (the samples' clock is this host's monotonic clock)."""
    asked = time.monotonic()
    give_up = asked + CATCH_UP_S
    while True:
        left = give_up - time.monotonic()
        if left <= 0.0 or not feed.poll(int(left * 1e3) + 1):
            return max(asked - archive.feed_t, 0.0) if archive.feed_t is not None else 0.0
        taken = _take_one(feed, archive, stop)
        if taken is not None and (not taken[0] or taken == (MARK, token)):  # END: nothing more will come
            return None


def _send(control, frames: list[bytes]) -> bool:
    """Frames to the messenger; False if none is connected (or it cannot take them now)."""
    import zmq
    try:
        control.send_multipart([MESSENGER_ID, *frames], zmq.NOBLOCK)
        return True
    except zmq.ZMQError:
        return False  # no messenger just now (restarting): a reply's client times out


def _send_event(control, held: list[list[bytes]], event: bytes) -> None:
    """An event to the messenger, after those held before it; held itself if none is connected."""
    held.append([EVENT, event])
    _send_held(control, held)


def _send_held(control, held: list[list[bytes]]) -> None:
    while held and _send(control, held[0]):
        held.pop(0)
    del held[:-EVENTS_HELD]  # (a messenger gone for long: the oldest go)
