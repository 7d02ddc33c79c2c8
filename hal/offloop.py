"""A transport whose exchange runs in its own process, so a slow round trip never stalls a
cycle: the loop posts its outputs and takes the latest inputs and their age from shared
memory, and never waits on the wire.

The worker process repeats, at the loop's rate: take the newest outputs, do one exchange
through its :class:`Link` (one Modbus read-write transaction, say), publish the inputs with
the time they came back. Each side of the shared memory is a seqlock (a counter that is odd
while a write is under way), so neither side ever blocks the other. A worker at normal
priority is ordinary Python and holds no lock the loop needs; ``worker_priority`` puts it at
SCHED_FIFO (below the loop) on a rig where the exchange must keep pace.

What the loop sees:
- a new sample: its values and its age, mapped onto the loop's clock;
- no new sample: the previous one again with its old time, so a peer that stops answering
  trips the supervisor on stale input;
- a link that is down (the peer refused, reset or timed out): TransportError with the
  worker's own words, so the trip says why. The worker keeps trying to reconnect every
  ``reopen_every_s``; once samples flow again the supervisor waits for a reset.
Malformed replies (exception responses, wrong lengths) are counted, never fatal.

The worker is a helper process (:class:`hal.process.Helper`): it dies with the daemon and says
it is ready with its first sample. If it dies, no new sample comes (the supervisor trips on
stale input) until the loop's next look (:meth:`OffLoopTransport.check_worker`, every 0.1 s:
meanwhile nothing writes to the peer) starts another, which reconnects to the peer; then
``reset`` and ``enable``, as after the peer's own death.
"""
from __future__ import annotations

import ctypes
import os
import time
import weakref
from collections.abc import Callable, Sequence

from hal.errors import TransportError, TransportTimeout
from hal.process import Child, Helper, HelperFailed, SharedMemory
from hal.seqlock import read_locked, try_read, write_locked
from hal.transport import (
    FULL_SCALE_COUNTS,
    InputSweep,
    Transport,
    counts_to_volts,
    volts_to_counts,
)

COUNTERS = ("exchanges", "timeouts", "exception_replies", "bad_replies", "link_lost", "reconnects")
_ERROR_BYTES = 240
LOOP_READ_TRIES = 200  # the loop's side: a few microseconds, then the last whole sample
OUTPUTS_PATIENCE_S = 1.0  # the exchange waits this long for the loop to finish writing its outputs [s]


class LinkDown(Exception):
    """The peer cannot be reached: reconnect before the next exchange."""


class LinkTimeout(LinkDown):
    """The peer did not answer in time."""


class BadReply(Exception):
    """The peer answered, wrongly (``counter`` says how); the link stays up."""

    def __init__(self, message: str, counter: str = "bad_replies"):
        super().__init__(message)
        self.counter = counter


class Link:
    """The wire, as the worker process uses it: built there from picklable options."""

    def connect(self) -> None:
        """Raise LinkDown if the peer cannot be reached."""

    def exchange(self, outputs: Sequence[int]) -> Sequence[int]:
        """Send the output counts, return the input counts; LinkDown or BadReply."""
        raise NotImplementedError

    def close(self) -> None:
        pass


def _shared(n_in: int, n_out: int) -> SharedMemory:
    """The memory both processes map: the inputs' seqlock, the reply's time.monotonic(), the
    outputs' seqlock, the link's state, the stop flag, the last error, the counters."""
    return SharedMemory({"in_seq": ctypes.c_uint64, "in_t": ctypes.c_double, "inputs": ctypes.c_double * n_in,
                         "out_seq": ctypes.c_uint64, "outputs": ctypes.c_double * n_out, "link_up": ctypes.c_bool,
                         "stop": ctypes.c_bool, "error": ctypes.c_char * _ERROR_BYTES,
                         "counters": ctypes.c_uint64 * len(COUNTERS)})


class OffLoopTransport(Transport):
    """Subclasses set ``backend`` and channels, and give :meth:`link_factory`. The link
    moves raw counts (``full_scale`` at a channel's high end)."""

    full_scale: int = FULL_SCALE_COUNTS

    def __init__(self, clock: Callable[[], float], rate_hz: float, open_timeout_s: float,
                 reopen_every_s: float, worker_priority: int, safe_outputs: Sequence[float] = ()):
        """``safe_outputs``: the rig's safe state [V], what the worker writes until the loop
        writes (default: 0 V, which a 5/3 valve takes as full speed one way)."""
        super().__init__()
        self.clock = clock
        self.safe_outputs = tuple(safe_outputs) or (0.0,) * len(self.outputs)
        self.rate_hz = rate_hz
        self.open_timeout_s = open_timeout_s
        self.reopen_every_s = reopen_every_s
        self.worker_priority = worker_priority
        self._shared: SharedMemory | None = None
        self._process: Helper | None = None
        self._sweep = InputSweep(0, float("-inf"), (0.0,) * len(self.inputs))
        self._last_seq = 0

    def link_factory(self) -> tuple[Callable[..., Link], tuple]:
        """A module-level callable and its picklable arguments that build the Link."""
        raise NotImplementedError

    # -- lifecycle --------------------------------------------------------------------------
    def open(self) -> None:
        """Spawn the worker and wait for its first sample: a peer that is not there stops
        the daemon at start with the worker's reason."""
        self._shared = shared = _shared(len(self.inputs), len(self.outputs))
        write_locked(shared.out_seq, shared.outputs, volts_to_counts(self.safe_outputs, self.outputs, self.full_scale))
        factory, args = self.link_factory()
        self._process = Helper("hal.offloop:serve", (shared, factory, args, 1.0 / self.rate_hz, self.reopen_every_s,
                                                    self.worker_priority),
                               name=f"the {self.backend} worker", pass_fds=(shared.fd,))
        # Dropped without close() (an exception on the way, a test that failed), the worker
        # must not outlive its transport: it would go on writing its outputs to the peer.
        self._finalizer = weakref.finalize(self, _stop_worker, shared, self._process)
        try:
            self._process.start(self.open_timeout_s)
        except HelperFailed as exc:
            reason = self._last_error() or str(exc)
            self.close()
            raise TransportTimeout(f"{self.backend}: no sample within {self.open_timeout_s:g} s of opening: {reason}") \
                from None
        super().open()

    def close(self) -> None:
        """Stop the worker once the outputs last posted are out (two more exchanges: the one
        under way may have taken older outputs), so a final safe state is not lost."""
        if self._process is not None:
            shared = self._shared
            flushed = shared.in_seq.value + 4
            deadline = time.monotonic() + 0.5
            while shared.link_up.value and shared.in_seq.value < flushed and time.monotonic() < deadline:
                time.sleep(0.001)
            self._finalizer.detach()
            _stop_worker(shared, self._process)
            self._process = None
        super().close()

    # -- the sweeps (loop side) -------------------------------------------------------------
    def read(self) -> InputSweep:
        shared = self._shared
        if shared is None:
            raise TransportError(f"{self.backend}: not open")
        found = try_read(shared.in_seq, shared.inputs, shared.in_t, LOOP_READ_TRIES)
        if found is None:  # the exchange is mid-write (descheduled there): the last whole sample,
            return self._sweep  # whose age the supervisor judges; the loop never spins on it
        seq, raw, t_reply = found
        self._health.reads += 1
        if seq != self._last_seq:
            self._last_seq = seq
            now = self.clock()
            t = now - max(time.monotonic() - t_reply, 0.0)  # the reply's time on the loop's clock
            self._sweep = InputSweep(self._sweep.seq + 1, t, counts_to_volts(raw, self.inputs, self.full_scale))
            self._health.last_sample_t = t
            return self._sweep
        if not shared.link_up.value:
            self._raise_link_down()
        return self._sweep

    def _write(self, values: Sequence[float]) -> None:
        shared = self._shared
        if shared is None:
            raise TransportError(f"{self.backend}: not open")
        # posted also while the link is down: a worker that reconnects (or a new one) sends the
        # newest outputs, the safe state after a trip, not those from before the link went
        write_locked(shared.out_seq, shared.outputs, volts_to_counts(values, self.outputs, self.full_scale))
        if not shared.link_up.value:
            self._raise_link_down()

    def check_worker(self) -> str | None:
        process, shared = self._process, self._shared
        if process is None:
            return None
        if process.exitcode() is None:
            try:
                process.poll_ready()  # (health: running once the new one has a sample)
            except HelperFailed:
                pass  # it exits: the next look starts another
            return None
        shared.link_up.value = False  # the new worker connects first; meanwhile the loop is told the link is down
        if shared.in_seq.value & 1:  # it died writing a sample: the half-written one is never read
            shared.in_seq.value += 1
            self._last_seq = shared.in_seq.value
        code = process.restart_if_dead()
        return (f"the {self.backend} exchange worker exited (code {code}) and was restarted (restart "
                f"{process.restarts}); it reconnects to its peer")

    def worker_health(self) -> dict | None:
        return self._process.health() if self._process is not None else None

    def _raise_link_down(self):
        alive = self._process is not None and self._process.alive
        reason = self._last_error() or "the link is down"
        if not alive:
            reason = f"the {self.backend} worker process has stopped ({reason})"
        raise TransportError(f"{self.backend}: {reason}")

    def _last_error(self) -> str:
        return self._shared.error.value.decode(errors="replace") if self._shared else ""

    def health(self):
        h = self._health
        if self._shared is not None:
            h.counters.update(zip(COUNTERS, self._shared.counters[:]))
            h.errors = sum(h.counters[k] for k in COUNTERS if k not in ("exchanges", "reconnects"))
            h.last_error = self._last_error()
        return h


def _stop_worker(shared: SharedMemory, process: Helper) -> None:
    """Ask the worker to stop, then make sure it has."""
    shared.stop.value = True
    process.join(2.0)


# -- in the worker process --------------------------------------------------------------------
def serve(child: Child, shared: SharedMemory, factory, args, period: float, reopen_every_s: float,
          priority: int) -> None:
    """The worker's main: exchange at the loop's rate until told to stop, or until the daemon
    is gone. An orphan must not go on writing the last outputs it was given: it would fight
    the dead-man command that writes the safe state after a crash (systemd's stop hook)."""
    if priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except OSError as exc:
            _error(shared, f"worker_priority {priority} not applied: {exc}")
    link = factory(*args)
    counters = shared.counters
    index = {name: i for i, name in enumerate(COUNTERS)}
    next_try = 0.0
    deadline = time.monotonic()
    while not shared.stop.value and child.parent_alive():
        if not shared.link_up.value:
            if time.monotonic() < next_try:
                time.sleep(0.005)
                continue
            try:
                link.connect()
                shared.link_up.value = True
                counters[index["reconnects"]] += 1
            except LinkDown as exc:
                _error(shared, str(exc))
                next_try = time.monotonic() + reopen_every_s
                continue
        _, outputs, _ = read_locked(shared.out_seq, shared.outputs, patience_s=OUTPUTS_PATIENCE_S)
        try:
            inputs = link.exchange(outputs)
        except LinkDown as exc:
            counters[index["timeouts" if isinstance(exc, LinkTimeout) else "link_lost"]] += 1
            _error(shared, str(exc))
            shared.link_up.value = False
            link.close()
            next_try = time.monotonic() + reopen_every_s
            continue
        except BadReply as exc:
            counters[index[exc.counter]] += 1
            _error(shared, str(exc))
        else:
            shared.in_seq.value += 1
            shared.inputs[:] = inputs
            shared.in_t.value = time.monotonic()
            shared.in_seq.value += 1
            counters[index["exchanges"]] += 1
            child.ready()  # (once: the first sample is there)
        deadline = max(deadline + period, time.monotonic())  # never burst to catch up
        time.sleep(max(deadline - time.monotonic(), 0.0))
    link.close()


def _error(shared: SharedMemory, message: str) -> None:
    shared.error.value = message.encode()[:_ERROR_BYTES - 1]
