"""What the loop's cycle watchdog (:mod:`daemon.loop.watchdog`) and the messenger tell each
other, in the rings' directory:

- ``estop``, a FIFO: the messenger writes a byte for every e-stop it passes to the loop, so
  that the watchdog, asleep in a ``select`` on it, writes the safe state at once when the loop
  does not take the e-stop itself within a few periods (a step that hangs); and, in the shared
  memory below, when it passed the last one [s, monotonic, the same clock in every process],
  which the watchdog holds against when the loop last took one: the FIFO's byte may reach the
  watchdog after the loop has taken its e-stop, and even reset since (a loaded PC);
- ``watchdog``, shared memory: each time the watchdog acted, its count, the loop's cycle
  count then, the time [s, monotonic], whether the safe state was written and the cause in
  words (written before the count, which the messenger polls), so the messenger publishes the
  ``watchdog`` event, answers the e-stops the write was for and says so in its
  ``loop_stalled`` answers while the loop itself cannot.

The loop's side creates both (:meth:`WatchdogLink.create`) before the messenger starts, and
keeps the FIFO's read end open, so the messenger's non-blocking open of its write end never
fails (a restarted messenger opens it again)."""
from __future__ import annotations

import mmap
import os
import struct
import time
from typing import NamedTuple

_HEAD = struct.Struct("<QQd")  # count, cycle, t
_PASSED = struct.Struct("<d")  # when the messenger last passed an e-stop to the loop [s, monotonic]
_PASSED_AT = _HEAD.size
_WRITTEN = _PASSED_AT + _PASSED.size  # one byte: 1 if the safe state was written
_CAUSE = _WRITTEN + 1
_CAUSE_BYTES = 480
_SIZE = _CAUSE + _CAUSE_BYTES


class Report(NamedTuple):
    """The watchdog's last act (count 0: none yet): the loop's cycle count and the time [s,
    monotonic] then, the cause in words, and whether the safe state was written (False: the
    cause says why it could not be)."""

    count: int
    cycle: int
    t: float
    cause: str
    written: bool


NONE = Report(0, 0, 0.0, "", False)


class WatchdogLink:
    def __init__(self, directory: str, create: bool = False):
        fifo, shared = os.path.join(directory, "estop"), os.path.join(directory, "watchdog")
        if create:
            os.mkfifo(fifo, 0o600)
            with open(shared, "wb") as f:
                f.truncate(_SIZE)
        # the loop's side reads the FIFO, the messenger's writes it; neither ever blocks on it. The
        # loop's side holds a write end too: with no writer (a messenger dead, not yet restarted)
        # a FIFO reads as at its end, which select would report ready at every call
        self.fd = os.open(fifo, (os.O_RDONLY if create else os.O_WRONLY) | os.O_NONBLOCK)
        self._writer = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK) if create else None
        fd = os.open(shared, os.O_RDWR)
        try:
            self._map = mmap.mmap(fd, _SIZE)
        finally:
            os.close(fd)

    @classmethod
    def create(cls, directory: str) -> "WatchdogLink":
        return cls(directory, create=True)

    # -- the messenger's side ---------------------------------------------------------------
    def pass_estop(self) -> None:
        """An e-stop goes to the loop (said before it is queued for it): note when, and wake the
        watchdog (a full FIFO has woken it already)."""
        _PASSED.pack_into(self._map, _PASSED_AT, time.monotonic())
        try:
            os.write(self.fd, b"!")
        except BlockingIOError:
            pass

    def report(self) -> Report:
        """The watchdog's last act (count 0: none)."""
        count, cycle, t = _HEAD.unpack_from(self._map, 0)
        cause = bytes(self._map[_CAUSE:_SIZE]).rstrip(b"\0").decode("utf-8", "replace")
        return Report(count, cycle, t, cause, self._map[_WRITTEN] == 1)

    # -- the watchdog's side ----------------------------------------------------------------
    def estop_passed_at(self) -> float:
        """When the messenger last passed an e-stop to the loop [s, monotonic; 0.0: never]. Read
        until two reads agree: the messenger's process may be writing it."""
        last = None
        while (now := _PASSED.unpack_from(self._map, _PASSED_AT)[0]) != last:
            last = now
        return now

    def drain(self) -> None:
        """Empty the FIFO (the e-stops passed so far are answered by one look)."""
        try:
            while os.read(self.fd, 64):
                pass
        except BlockingIOError:
            pass

    def wrote_safe(self, count: int, cycle: int, t: float, cause: str, written: bool) -> None:
        """Say the watchdog acted (``written``: the safe state was written): the cause first, the count last."""
        text = cause.encode("utf-8")[:_CAUSE_BYTES]
        self._map[_WRITTEN] = 1 if written else 0
        self._map[_CAUSE:_SIZE] = text + b"\0" * (_CAUSE_BYTES - len(text))
        _HEAD.pack_into(self._map, 0, count, cycle, t)

    def close(self) -> None:
        self._map.close()
        os.close(self.fd)
        if self._writer is not None:
            os.close(self._writer)
