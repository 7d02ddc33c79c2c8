"""The recorder: the daemon's own recordings, written in a process of their own beside the loop.

The messenger hands it every telemetry message as it leaves the loop's ring (a ZeroMQ PUSH
on a private ipc socket in the rings' directory, before any network), so a recording never
loses what a slow or stalled client would; what it does lose (its own queue full, a write
slower than the telemetry) shows as a ``gap`` in the file, from the topics' ``seq``. It
writes MCAP (:mod:`daemon.recordings.mcap_log`) into the daemon's recording directory.

Recordings start and stop by request (``record.start``, ``record.stop``, ``record.list``,
which the messenger passes here and never to the loop), or follow a reference: a motion
command with ``record: true`` has its ``reference`` start event name a recording, which runs
from that event to ``TAIL_S`` after the reference's end (or its cut, or the arm leaving
``enabled``). A write error or a full disk (less than ``min_free_mb`` left) ends a recording
with an event, the file readable up to its last complete chunk; the loop never knows.

The metadata of a recording (``describe``, the controller and its parameters) come from the
files the daemon writes into the rings' directory at start (``describe.json``,
``controller.json``), kept up to date from the ``controller`` and ``params`` events.

    python -c 'from daemon.recorder.process import main; main()' --rings DIR --directory DIR [--max-mb N] [--min-free-mb N]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import select
import signal
import subprocess
import sys
import time

FEED = "recorder-feed"  # ipc socket names in the rings' directory
CONTROL = "recorder-control"
MESSENGER_ID = b"messenger"  # the messenger's routing id on the control socket
FEED_HWM = 200_000  # messages the feed may queue (about 10 minutes of telemetry)
TAIL_S = 3.0  # a reference's recording runs on this long after its end: the settling (a step's response)
MAX_ACTIVE = 4
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,79}$")
START_TIMEOUT_S = 30.0


def endpoint(rings_dir: str, name: str) -> str:
    return f"ipc://{os.path.join(rings_dir, name)}"


class RecorderProcess:
    """The daemon's handle on the recorder process (started, restarted if it dies, joined)."""

    def __init__(self, rings_dir: str, directory: str, max_mb: float, min_free_mb: float):
        self.rings_dir, self.directory = rings_dir, directory
        self.args = ["--rings", rings_dir, "--directory", directory, "--max-mb", str(max_mb),
                     "--min-free-mb", str(min_free_mb)]
        self.restarts = 0
        self._proc: subprocess.Popen | None = None

    def start(self) -> None:
        self._spawn()
        if not select.select([self._proc.stdout], [], [], START_TIMEOUT_S)[0] or \
                not (line := self._proc.stdout.readline().strip()).startswith("ready"):
            self._proc.kill()
            self._proc.wait()
            raise RuntimeError(f"the recorder did not start: {line if 'line' in locals() else 'no answer'}")

    def _spawn(self) -> None:
        self._proc = subprocess.Popen([sys.executable, "-c", "import sys; from daemon.recorder.process import main; "
                                       "sys.exit(main())", *self.args], stdout=subprocess.PIPE, text=True)

    def check(self) -> str | None:
        """Called once a second from the loop, never blocking: a dead recorder is started again
        (its recordings in progress end where they were); what happened, as an event's cause."""
        code = self._proc.poll()
        if code is None:
            return None
        self.restarts += 1
        self._proc.stdout.close()
        self._spawn()
        return f"the recorder process exited (code {code}) and was restarted (restart {self.restarts}); " \
               f"its recordings in progress end where they were"

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def join(self, timeout: float = 5.0) -> None:
        """Wait for the process to finish its files once the messenger has ended the feed."""
        if self._proc is None:
            return
        try:
            self._proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self._proc.terminate()  # finishes its files too
            try:
                self._proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._proc.stdout.close()
        self._proc = None


def write_metadata(rings_dir: str, describe: dict, controller: dict) -> None:
    """The daemon's ``describe`` and its controller at start, for the recorder (start-up only)."""
    for name, doc in (("describe.json", describe), ("controller.json", controller)):
        with open(os.path.join(rings_dir, name), "w") as f:
            json.dump(doc, f)


# -- in the recorder process ----------------------------------------------------------------
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="pneumad-recorder", description=__doc__)
    ap.add_argument("--rings", required=True)
    ap.add_argument("--directory", required=True)
    ap.add_argument("--max-mb", type=float, default=2048.0)
    ap.add_argument("--min-free-mb", type=float, default=200.0)
    args = ap.parse_args(argv)
    import zmq

    from daemon.recorder.archive import Archive
    from daemon.service.realtime import leave_real_time
    stop = []
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the daemon ends the feed when it stops
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a file-size limit is a write error, not death
    _term_with_parent()
    leave_real_time(sorted(os.sched_getaffinity(0)), nice=5)
    parent = os.getppid()
    ctx = zmq.Context()
    feed, control = ctx.socket(zmq.PULL), ctx.socket(zmq.ROUTER)
    feed.setsockopt(zmq.RCVHWM, FEED_HWM)
    control.setsockopt(zmq.ROUTER_HANDOVER, 1)  # a restarted messenger takes its id over
    for sock in (feed, control):
        sock.setsockopt(zmq.LINGER, 0)
    feed.bind(endpoint(args.rings, FEED))
    control.bind(endpoint(args.rings, CONTROL))
    archive = Archive(args.rings, args.directory, args.max_mb * 1e6, args.min_free_mb * 1e6,
                      lambda event: _send(control, [b"event", json.dumps(event).encode()]))
    print("ready", flush=True)
    poller = zmq.Poller()
    poller.register(feed, zmq.POLLIN)
    poller.register(control, zmq.POLLIN)
    while not stop and os.getppid() == parent:
        ready = dict(poller.poll(200))
        if control in ready:
            while True:
                try:
                    frames = control.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                if len(frames) == 4:  # [routing id, token, who, request]
                    _send(control, [b"reply", frames[1], archive.request(frames[3], frames[2].decode(errors="replace"))])
        if feed in ready:
            for _ in range(1000):  # a bounded batch, then the requests again
                try:
                    topic, body = feed.recv_multipart(zmq.NOBLOCK)
                except (zmq.Again, ValueError):
                    break
                if not topic:  # the messenger passed on the loop's END
                    stop.append(1)
                    break
                archive.message(topic.decode(), body)
        archive.tick(time.monotonic())
    archive.close("the daemon stopped")
    feed.close()
    control.close()
    ctx.term()
    return 0


def _send(control, frames: list[bytes]) -> None:
    import zmq
    try:
        control.send_multipart([MESSENGER_ID, *frames], zmq.NOBLOCK)
    except zmq.ZMQError:
        pass  # no messenger just now (restarting): the client's time-out tells it


def _term_with_parent() -> None:
    """SIGTERM when the daemon dies: the recorder finishes its files (prctl PR_SET_PDEATHSIG)."""
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)
    except (OSError, AttributeError):
        pass
