"""Analog I/O over CAN (python-can): any interface python-can has (socketcan on the lab PC,
``virtual`` in one process, ``udp_multicast`` across processes on one machine).

Frames (ids in the rig file): the outputs go in frames from ``output_id`` on, the inputs
come in frames from ``input_id`` on, four channels per frame as uint16 little-endian raw
counts (0 at the channel's low end, 65535 at its high end), in the order of
:func:`hal.transport.rig_channels`; the last frame carries what is left. An output frame
with no data is a query: the peer answers with the inputs and changes nothing.

Like the serial bridge the exchange is pipelined and never blocks the loop: ``write`` sends
the output frames, the peer answers with input frames, the next ``read`` drains what has
arrived. A sample is complete when the last input frame arrives. CAN has no connection: a
peer that dies simply stops answering, and the supervisor trips on stale input
(``safety.stale_after_s``). Frames with ids that belong to neither side, or with the wrong
length, are counted, never fatal; a bus error on sending is a TransportError.
"""
from __future__ import annotations

import struct
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import can

from hal.errors import TransportError, TransportTimeout
from hal.schema import build, require
from hal.transport import (
    InputSweep,
    Transport,
    counts_to_volts,
    rig_channels,
    volts_to_counts,
)

PER_FRAME = 4
MAX_DRAIN = 64  # frames taken per read: a flood cannot hold the loop


@dataclass(frozen=True)
class CanOptions:
    """``[transport.options]`` when ``backend = "can"``."""

    interface: str = "socketcan"
    channel: str = "can0"
    output_id: int = 0x200
    input_id: int = 0x180
    open_timeout_s: float = 2.0
    port: int | None = None  # udp_multicast only: its UDP port (python-can's default, 43113, when unset)

    def __post_init__(self):
        require(bool(self.interface), "interface", "must name a python-can interface")
        require(self.port is None or (self.interface == "udp_multicast" and 0 < self.port < 65536), "port",
                "is udp_multicast's UDP port (1-65535), for no other interface")
        require(0 <= self.output_id < 0x800 and 0 <= self.input_id < 0x800, "output_id",
                "ids must be 11-bit (0-0x7FF)")
        require(0 < self.open_timeout_s <= 30, "open_timeout_s", "must be within (0, 30] s")


def bus_port(port: int | None) -> dict:
    """``can.Bus``'s keyword for a udp_multicast port: a group's traffic reaches every socket of
    the machine on its port (Linux's IP_MULTICAST_ALL), so two buses apart need ports apart."""
    return {} if port is None else {"port": port}


def frame_ids(first: int, channels: int) -> range:
    return range(first, first + (channels + PER_FRAME - 1) // PER_FRAME)


def pack(counts: Sequence[int]) -> list[bytes]:
    """Counts into frame payloads, four per frame."""
    return [struct.pack(f"<{len(part)}H", *part) for part in
            (counts[i:i + PER_FRAME] for i in range(0, len(counts), PER_FRAME))]


class CanTransport(Transport):
    backend = "can"
    rate_hz = 1000.0

    def __init__(self, rig, options: CanOptions, clock: Callable[[], float]):
        super().__init__()
        self.open_timeout_s = options.open_timeout_s
        self.options = options
        self.clock = clock
        self.inputs, self.outputs, _ = rig_channels(rig)
        self._in_ids = frame_ids(options.input_id, len(self.inputs))
        self._out_ids = frame_ids(options.output_id, len(self.outputs))
        self._parts: list[tuple[int, ...] | None] = [None] * len(self._in_ids)
        self._bus: can.BusABC | None = None
        self._sweep = InputSweep(0, float("-inf"), (0.0,) * len(self.inputs))
        for key in ("wrong_ids", "bad_lengths", "bus_errors", "flooded"):
            self._health.counters[key] = 0

    @classmethod
    def from_config(cls, rig, clock):
        return cls(rig, build(CanOptions, rig.transport.options, "transport.options"), clock)

    def open(self) -> None:
        """Join the bus and query the peer every 50 ms until it answers."""
        o = self.options
        try:
            self._bus = can.Bus(interface=o.interface, channel=o.channel, **bus_port(o.port))
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            raise TransportError(f"can: cannot open {o.interface} channel {o.channel}: {exc}") from None
        deadline = time.monotonic() + o.open_timeout_s
        next_query = 0.0
        while time.monotonic() < deadline:
            if time.monotonic() >= next_query:  # again and again: a node may still be booting
                self._send([b""])
                next_query = time.monotonic() + 0.05
            if self._receive():
                super().open()
                return
            time.sleep(0.001)
        self.close()
        raise TransportTimeout(f"can: no answer on {o.interface} channel {o.channel} (input frames from "
                               f"{o.input_id:#x}) within {o.open_timeout_s:g} s")

    def close(self) -> None:
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None
        super().close()

    def read(self) -> InputSweep:
        if self._bus is None:
            raise TransportError("can: not open")
        self._receive()
        self._health.reads += 1
        return self._sweep

    def _write(self, values: Sequence[float]) -> None:
        if self._bus is None:
            raise TransportError("can: not open")
        self._send(pack(volts_to_counts(values, self.outputs)))

    def _send(self, payloads: list[bytes]) -> None:
        try:
            for arbitration_id, data in zip(self._out_ids, payloads):
                self._bus.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))
        except can.CanError as exc:
            self._health.counters["bus_errors"] += 1
            self._health.errors += 1
            self._health.last_error = f"can: send failed: {exc}"
            raise TransportError(self._health.last_error) from None

    def _receive(self) -> bool:
        """Take the frames waiting (at most MAX_DRAIN); True if a sample was completed."""
        counters, fresh = self._health.counters, False
        for _ in range(MAX_DRAIN):
            try:
                msg = self._bus.recv(timeout=0)
            except can.CanError as exc:
                counters["bus_errors"] += 1
                raise TransportError(f"can: receive failed: {exc}") from None
            if msg is None:
                return fresh
            index = msg.arbitration_id - self._in_ids.start
            if msg.is_extended_id or msg.is_error_frame or not 0 <= index < len(self._in_ids):
                if msg.arbitration_id not in self._out_ids:  # our own frames echo on some buses
                    counters["wrong_ids"] += 1
                continue
            expected = min(PER_FRAME, len(self.inputs) - PER_FRAME * index)
            if msg.dlc != 2 * expected:
                counters["bad_lengths"] += 1
                continue
            self._parts[index] = struct.unpack(f"<{expected}H", bytes(msg.data))
            if index == len(self._in_ids) - 1 and all(p is not None for p in self._parts):
                now = self.clock()
                counts = [c for part in self._parts for c in part]
                self._sweep = InputSweep(self._sweep.seq + 1, now, counts_to_volts(counts, self.inputs))
                self._health.last_sample_t = now
                fresh = True
        counters["flooded"] += 1
        return fresh
