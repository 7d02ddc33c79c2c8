"""The frame protocol of the serial DAQ bridge (docs/serial-bridge.md): framing, sequence
numbers and a CRC, so the host can tell a good exchange from line noise.

    offset  size  field
    0       2     sync        0xA5 0x5A
    2       1     kind        0x01 outputs (host -> bridge), 0x81 inputs (bridge -> host)
    3       2     seq         uint16 little-endian; a reply carries the seq of its request
    5       1     length      payload bytes, at most MAX_PAYLOAD
    6       n     payload     uint16 little-endian raw counts, one per channel
    6+n     2     crc         CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over kind..payload

The reader is incremental: it takes whatever bytes the port gave (split frames, partial
frames, garbage between them) and returns the complete frames that pass their CRC, counting
what it had to throw away. After a bad frame it resynchronises on the next sync pattern,
which may start inside the bytes it rejected.
"""
from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass

SYNC = b"\xa5\x5a"
OUTPUTS = 0x01
INPUTS = 0x81
KINDS = (OUTPUTS, INPUTS)
MAX_PAYLOAD = 64  # 32 channels of 16 bits
_HEADER = struct.Struct("<2sBHB")
_CRC = struct.Struct("<H")
OVERHEAD = _HEADER.size + _CRC.size


@dataclass(frozen=True)
class Frame:
    kind: int
    seq: int
    counts: tuple[int, ...]  # raw counts per channel, 0..65535


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (binascii's CRC-CCITT with the 0xFFFF start)."""
    return binascii.crc_hqx(data, 0xFFFF)


def encode(kind: int, seq: int, counts) -> bytes:
    """One frame; ValueError for a kind, seq, count or channel number the protocol cannot carry."""
    if kind not in KINDS:
        raise ValueError(f"unknown frame kind {kind:#x}")
    if not 0 <= seq <= 0xFFFF:
        raise ValueError(f"sequence number {seq} is not a uint16")
    if 2 * len(counts) > MAX_PAYLOAD:
        raise ValueError(f"{len(counts)} channels: a frame carries at most {MAX_PAYLOAD // 2}")
    try:
        payload = struct.pack(f"<{len(counts)}H", *counts)
    except struct.error as exc:
        raise ValueError(f"counts must be integers 0..65535: {exc}") from None
    body = _HEADER.pack(SYNC, kind, seq, len(payload)) + payload
    return body + _CRC.pack(crc16(body[2:]))


@dataclass
class ReaderStats:
    frames: int = 0
    crc_errors: int = 0
    bad_headers: int = 0  # unknown kind, odd or oversized length
    discarded_bytes: int = 0  # bytes skipped while looking for a sync pattern


class FrameReader:
    """Feed it bytes as they come; it returns the good frames in them."""

    def __init__(self):
        self._buf = bytearray()
        self.stats = ReaderStats()

    def feed(self, data: bytes) -> list[Frame]:
        self._buf += data
        frames = []
        while (frame := self._next()) is not None:
            frames.append(frame)
        return frames

    def clear(self) -> None:
        """Forget a partial frame (the port was reopened)."""
        self._buf.clear()

    def _next(self) -> Frame | None:
        buf, stats = self._buf, self.stats
        while True:
            start = buf.find(SYNC)
            if start < 0:  # keep a last byte that may be the first half of a sync
                keep = 1 if buf[-1:] == SYNC[:1] else 0
                stats.discarded_bytes += len(buf) - keep
                del buf[:len(buf) - keep]
                return None
            stats.discarded_bytes += start
            del buf[:start]
            if len(buf) < _HEADER.size:
                return None
            _, kind, seq, length = _HEADER.unpack_from(buf)
            if kind not in KINDS or length > MAX_PAYLOAD or length % 2:
                stats.bad_headers += 1
                self._skip_sync()
                continue
            end = _HEADER.size + length + _CRC.size
            if len(buf) < end:
                return None
            (crc,) = _CRC.unpack_from(buf, end - _CRC.size)
            if crc != crc16(bytes(buf[2:end - _CRC.size])):
                stats.crc_errors += 1
                self._skip_sync()
                continue
            counts = struct.unpack_from(f"<{length // 2}H", buf, _HEADER.size)
            del buf[:end]
            stats.frames += 1
            return Frame(kind, seq, counts)

    def _skip_sync(self) -> None:
        """Drop this sync pattern and look for the next one, which may lie inside the frame."""
        del self._buf[:len(SYNC)]
        self.stats.discarded_bytes += len(SYNC)
