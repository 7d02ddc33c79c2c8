"""A single-producer, single-consumer queue of tagged byte messages in shared memory.

The loop and the messenger process (:mod:`daemon.messenger.process`) talk through these, so the loop
never blocks on the other side and makes no system call to pass a message: a put is a copy
into a mapped file and a counter update, a get is a counter read and a copy out. A full ring
refuses the message (the producer counts the drop); an empty one answers None.

Layout of the mapped file: ``written`` and ``read`` (u64, the bytes ever put and ever taken,
each changed by one side only), then the data area, a circle of ``capacity`` bytes. An entry
is a header (payload length u32, tag u64) and the payload, split across the circle's end when
it falls there. The producer copies an entry in before it advances ``written``; the consumer
copies it out before it advances ``read``. x86-64 keeps stores in program order (TSO), which
is what makes this safe without a lock, as for the seqlock of :mod:`hal.offloop`.
"""
from __future__ import annotations

import ctypes
import mmap
import os
import struct

_ENTRY = struct.Struct("<IQ")  # payload length, tag
_DATA = 64  # the counters get a cache line of their own


class RingError(RuntimeError):
    """The ring holds something its producer cannot have written (a bug, never input)."""


class Ring:
    def __init__(self, path: str, capacity: int = 0):
        """Map the ring in the file at ``path``; with ``capacity`` [bytes], create it first."""
        if capacity:
            with open(path, "wb") as f:
                f.truncate(_DATA + capacity)
        fd = os.open(path, os.O_RDWR)
        try:
            self._map = mmap.mmap(fd, os.fstat(fd).st_size)
        finally:
            os.close(fd)
        self.path = path
        self.capacity = len(self._map) - _DATA
        self._written = ctypes.c_uint64.from_buffer(self._map, 0)
        self._read = ctypes.c_uint64.from_buffer(self._map, 8)
        self._data = memoryview(self._map)[_DATA:]

    def free(self) -> int:
        """Bytes a put may use now (an entry takes its payload plus 12)."""
        return self.capacity - (self._written.value - self._read.value)

    def pending(self) -> bool:
        """Whether an entry waits to be taken (for a reader that would rather wait than poll)."""
        return self._read.value != self._written.value

    def put(self, tag: int, payload) -> bool:
        """Queue ``payload`` (bytes-like, copied before this returns) with ``tag``; False
        (nothing written) if it does not fit. An entry that fits before the circle's end is
        written in place, header and payload, with no copy made on the way: the loop's state
        batches are a few kilobytes, and the temporary copies cost its cycle more than the
        copy into the ring."""
        size = _ENTRY.size + len(payload)
        written = self._written.value
        if size > self.capacity - (written - self._read.value):
            return False
        at = written % self.capacity
        if at + size <= self.capacity:  # in one piece: header and payload straight into the ring
            _ENTRY.pack_into(self._data, at, len(payload), tag)
            self._data[at + _ENTRY.size:at + size] = payload
        else:
            self._copy_in(at, _ENTRY.pack(len(payload), tag) + bytes(payload))
        self._written.value = written + size
        return True

    def get(self) -> tuple[int, bytes] | None:
        """The oldest entry as (tag, payload), or None if there is none."""
        read = self._read.value
        if read == self._written.value:
            return None
        at = read % self.capacity
        length, tag = _ENTRY.unpack(self._copy_out(at, _ENTRY.size))
        if length > self.capacity - _ENTRY.size:
            raise RingError(f"ring {self.path}: an entry claims {length} bytes in a {self.capacity}-byte ring")
        payload = self._copy_out((at + _ENTRY.size) % self.capacity, length)
        self._read.value = read + _ENTRY.size + length
        return tag, payload

    def discard(self) -> None:
        """Drop whatever is queued: the consumer's way back to a known state after a RingError."""
        self._read.value = self._written.value

    def _copy_in(self, at: int, data: bytes) -> None:
        first = min(len(data), self.capacity - at)
        self._data[at:at + first] = data[:first]
        if first < len(data):
            self._data[:len(data) - first] = data[first:]

    def _copy_out(self, at: int, size: int) -> bytes:
        if at + size <= self.capacity:
            return self._data[at:at + size].tobytes()
        first = self.capacity - at
        return self._data[at:].tobytes() + self._data[:size - first].tobytes()

    def close(self) -> None:
        """Unmap (the file stays: the other side may still use it)."""
        self._data.release()
        del self._written, self._read
        self._map.close()
