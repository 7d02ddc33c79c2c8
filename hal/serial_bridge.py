"""A microcontroller I/O bridge on a serial line (pyserial), frames of docs/serial-bridge.md.

One exchange per cycle, pipelined so the loop never waits on the wire: ``write`` sends the
outputs frame (seq k) at the end of a cycle; the bridge answers with the inputs it sampled
after applying them, and the next cycle's ``read`` takes whatever replies have arrived
without blocking (about 1 ms later, the reply to k). The seq says which request a reply
answers: the sample is dated when that request went out (the bridge sampled after it, so the
age is never understated), and a reply to no recent request of ours, or older than one
already taken, is counted and dropped. "Recent" covers the largest stale limit: a bridge held
up for a while answers its backlog with samples as old as they are, which the stale check
judges, rather than with replies dropped as strangers (a window of 64 made a bridge 65 ms
behind look silent until it had caught up). A cycle with no new reply returns the previous
sample again (same seq, its old time), so a bridge that stops answering ages the data until
the supervisor trips on stale input (``safety.stale_after_s``).

Only ``open`` blocks: it sends the first frame and waits for the bridge's answer, so a
missing or silent bridge stops the daemon at start with a clear error. A port that vanishes
(a USB bridge unplugged, the simulator's pty closed) raises TransportError from every sweep
until the port can be opened again; the transport retries that every ``reopen_every_s`` and
then carries on, while the supervisor holds the fault until someone resets it.

Raw counts are 16 bits over each channel's span: counts = round((V - low) / (high - low) 65535).
"""
from __future__ import annotations

import os
import select
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import serial

from hal import serial_frames as F
from hal.errors import TransportError, TransportTimeout
from hal.schema import build, require
from hal.transport import (
    InputSweep,
    Transport,
    counts_to_volts,
    rig_channels,
    volts_to_counts,
)

SEQ_WINDOW = 4096  # replies to the last this many requests are accepted: 4 s at 1 kHz, past any stale limit (<= 1 s)


@dataclass(frozen=True)
class SerialBridgeOptions:
    """``[transport.options]`` when ``backend = "serial"``."""

    port: str  # e.g. /dev/ttyACM0, or the link the simulator's peer prints
    baudrate: int = 921600  # a 5-input frame pair is 36 bytes: 0.4 ms at this rate
    open_timeout_s: float = 1.0  # the bridge must answer the first frame within this
    reopen_every_s: float = 0.5  # after the port is lost, try it again this often

    def __post_init__(self):
        require(bool(self.port), "port", "must name the serial device")
        require(self.baudrate > 0, "baudrate", "must be > 0")
        require(0 < self.open_timeout_s <= 30, "open_timeout_s", "must be within (0, 30] s")
        require(0 < self.reopen_every_s <= 60, "reopen_every_s", "must be within (0, 60] s")


class SerialBridgeTransport(Transport):
    backend = "serial"
    rate_hz = 1000.0

    def __init__(self, rig, options: SerialBridgeOptions, clock: Callable[[], float]):
        super().__init__()
        self.options = options
        self.clock = clock
        self.open_timeout_s = options.open_timeout_s
        self.inputs, self.outputs, _ = rig_channels(rig)
        self._port: serial.Serial | None = None
        self._reader = F.FrameReader()
        self._tx_seq = 0
        self._sent_at = [(-1, 0.0)] * SEQ_WINDOW  # (seq, when its request went out) of recent requests
        self._sweep = InputSweep(0, float("-inf"), (0.0,) * len(self.inputs))
        self._next_reopen = 0.0
        self._lost = ""
        counters = self._health.counters
        for key in ("crc_errors", "bad_headers", "discarded_bytes", "wrong_replies", "unexpected_seq", "tx_dropped",
                    "port_lost", "reopened"):
            counters[key] = 0

    @classmethod
    def from_config(cls, rig, clock):
        return cls(rig, build(SerialBridgeOptions, rig.transport.options, "transport.options"), clock)

    # -- lifecycle ------------------------------------------------------------------------
    def open(self) -> None:
        """Open the port and exchange one frame with the bridge before anything else."""
        self._open_port()
        self._handshake()
        super().open()

    def close(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None
        super().close()

    def _open_port(self) -> None:
        """pyserial opens and configures the port (raw, non-blocking); the sweeps then use
        its file descriptor directly: pyserial's own non-blocking write spins on EAGAIN."""
        try:
            self._port = serial.Serial(self.options.port, self.options.baudrate, timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._port = None
            raise TransportError(f"serial: cannot open {self.options.port}: {exc}") from None
        self._reader.clear()

    def _handshake(self) -> None:
        """Ask for the inputs (an outputs frame with no payload, which changes no output:
        the bridge holds its safe outputs until the loop writes) and wait for the answer."""
        self._send(())
        deadline = time.monotonic() + self.options.open_timeout_s
        while time.monotonic() < deadline:
            if self._receive():
                return
            time.sleep(0.001)
        self.close()
        raise TransportTimeout(f"serial: no answer from the bridge on {self.options.port} within "
                               f"{self.options.open_timeout_s:g} s")

    # -- the sweeps -----------------------------------------------------------------------
    def read(self) -> InputSweep:
        self._ensure_port()
        self._receive()
        self._health.reads += 1
        return self._sweep

    def _write(self, values: Sequence[float]) -> None:
        self._ensure_port()
        self._send(volts_to_counts(values, self.outputs))

    def _send(self, counts) -> None:
        self._tx_seq = (self._tx_seq + 1) & 0xFFFF
        self._sent_at[self._tx_seq % SEQ_WINDOW] = (self._tx_seq, self.clock())
        frame = F.encode(F.OUTPUTS, self._tx_seq, counts)
        try:
            if os.write(self._port.fileno(), frame) < len(frame):
                self._health.counters["tx_dropped"] += 1  # cut short: the bridge drops it on its CRC
        except BlockingIOError:
            self._health.counters["tx_dropped"] += 1  # the bridge is not reading; the inputs will go stale
        except OSError as exc:
            self._lose(exc)

    def _receive(self) -> bool:
        """Take every complete reply waiting; True if a new sample came in."""
        fd = self._port.fileno()
        data = b""
        if select.select([fd], [], [], 0)[0]:
            try:
                data = os.read(fd, 4096)
            except BlockingIOError:
                pass
            except OSError as exc:
                self._lose(exc)
            else:  # readable, and then empty: how a tty says its device is gone (as pyserial reads it)
                if not data:
                    self._lose(EOFError("the device reports data but returns none (disconnected?)"))
        frames = self._reader.feed(data) if data else ()
        self._count_reader()
        fresh, sent = None, self._sweep.t
        for frame in frames:
            seq, t = self._sent_at[frame.seq % SEQ_WINDOW]
            if frame.kind != F.INPUTS or len(frame.counts) != len(self.inputs):
                self._health.counters["wrong_replies"] += 1
            elif seq != frame.seq or t < sent:
                self._health.counters["unexpected_seq"] += 1  # no request of ours, or older than one taken
            else:
                fresh, sent = frame, t
        if fresh is None:
            return False
        self._sweep = InputSweep(self._sweep.seq + 1, sent, counts_to_volts(fresh.counts, self.inputs))
        self._health.last_sample_t = sent
        return True

    def _count_reader(self) -> None:
        stats, counters = self._reader.stats, self._health.counters
        counters["crc_errors"], counters["bad_headers"] = stats.crc_errors, stats.bad_headers
        counters["discarded_bytes"] = stats.discarded_bytes

    # -- a port that vanishes and comes back ------------------------------------------------
    def _lose(self, exc: Exception):
        if self._port is not None:
            self._port.close()
            self._port = None
        self._lost = f"serial port {self.options.port} lost: {exc}"
        self._health.counters["port_lost"] += 1
        self._health.errors += 1
        self._health.last_error = self._lost
        self._next_reopen = time.monotonic() + self.options.reopen_every_s
        raise TransportError(self._lost)

    def _ensure_port(self) -> None:
        """Raise while the port is lost; reopen it when its time comes."""
        if self._port is not None:
            return
        if time.monotonic() < self._next_reopen:
            raise TransportError(self._lost or f"serial port {self.options.port} is not open")
        self._next_reopen = time.monotonic() + self.options.reopen_every_s
        self._open_port()  # raises TransportError while the device is still gone
        self._health.counters["reopened"] += 1
