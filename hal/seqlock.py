"""Seqlocks over shared memory: one writer, any number of readers, and neither ever blocks
the other. The writer makes the sequence number odd while it writes; a reader copies the
values and accepts them if the number was even and unchanged across the copy. What the
off-loop transports and the sensors beside the loop share with it."""
from __future__ import annotations

import time

READ_TRIES = 100_000  # a write takes about a microsecond; this is tens of milliseconds


class HalfWritten(RuntimeError):
    """The shared values stay half-written: their writer stopped in the middle."""


def write_locked(seq, array, values) -> None:
    seq.value += 1  # odd: a write is under way
    array[:] = values
    seq.value += 1


def try_read(seq, array, extra=None, tries: int = READ_TRIES):
    """(sequence number, values, extra.value) read consistently, retrying across a write up to
    ``tries`` times; None if the writer is still in the middle of one."""
    for _ in range(tries):
        before = seq.value
        if before & 1:
            continue
        values = array[:]
        more = extra.value if extra is not None else None
        if seq.value == before:
            return before, values, more
    return None


def read_locked(seq, array, extra=None, patience_s: float = 0.0):
    """As :func:`try_read`, but :class:`HalfWritten` if no consistent read comes (a writer that
    died halfway through). After spinning, it sleeps and retries for ``patience_s``: a writer
    descheduled in the middle of its write (a busy machine) is not a dead one, and spinning
    would only keep it from the CPU."""
    give_up = time.monotonic() + patience_s
    while True:
        found = try_read(seq, array, extra)
        if found is not None:
            return found
        if time.monotonic() >= give_up:
            raise HalfWritten("shared sample stays half-written: its writer stopped in the middle")
        time.sleep(0.0005)
