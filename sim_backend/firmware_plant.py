"""The simulated rig's plant behind the serial bridge's firmware built for this machine
(``make -C firmware/serial-bridge host``): the real firmware code on a pseudo-terminal, its
board's converters bound to the plant here, so a daemon on ``backend = "serial"`` drives it
as it would a bridge on USB.

    python -m sim_backend.firmware_plant --firmware BUILD/bridge-host [--config RIG] [--link /tmp/pneumad-bridge]
        [--layout cylinder-2] [--corrupt-every N]

The firmware process reaches the plant on a SOCK_SEQPACKET socket pair made here (its end
passed as ``--plant-fd``), in messages that firmware/serial-bridge/host/host.c sends:

    'H' n_in n_out safe_out[n_out] name  ->  'K', or 'E' and why: its layout (channel counts,
                                             safe outputs) must be the rig file's
    'W' t_us gap_us counts[n_out]        ->  (none) the DACs were updated: the rig's outputs
    'S'                                  ->  counts[n_in]: the rig's inputs, stepped to now

(little-endian; t_us and gap_us uint32 microseconds of the firmware's clock, counts uint16 over
each channel's 0..10 V). The plant is :class:`WiredRig` without its watchdog: the dead-man is
the firmware's own, and every DAC update is kept (``updates``) for what a test checks of it.
"""
from __future__ import annotations

import argparse
import select
import signal
import socket
import struct
import subprocess
import sys
from collections import deque
from typing import NamedTuple

from hal import config
from hal.transport import volts_to_counts
from sim_backend.serial_peer import DEFAULT_LINK
from sim_backend.wired import WiredRig

_UPDATE = struct.Struct("<cII")
KEEP_UPDATES = 200_000  # over three minutes of 1 kHz updates


class DacUpdate(NamedTuple):
    t_us: int  # the firmware's clock when it updated its DACs [us, uint32]
    gap_us: int  # since its previous look at the line and the clock [us]
    counts: tuple[int, ...]  # the outputs, counts over 0..10 V


class FirmwarePlant:
    """Serves one firmware process's board: its DAC updates drive the rig, its ADC sweeps sample it."""

    def __init__(self, rig, sock: socket.socket):
        self.rig = WiredRig(rig)
        self.sock = sock
        self.safe_counts = tuple(volts_to_counts(self.rig.safe_volts, self.rig.sim.outputs))
        self.updates: deque[DacUpdate] = deque(maxlen=KEEP_UPDATES)
        self.samples = 0
        self.layout = ""  # the firmware's layout, once it said hello
        self.refused = ""  # why its layout was refused

    def serve(self, stop=lambda: False) -> None:
        """Answer the firmware until ``stop()`` or until it goes away."""
        while not stop():
            if not select.select([self.sock], [], [], 0.05)[0]:
                continue
            try:
                msg = self.sock.recv(512)
            except OSError:
                return
            if not msg:
                return  # the firmware exited
            try:
                self._take(msg)
            except OSError:  # it exited while we answered
                return

    def _take(self, msg: bytes) -> None:
        kind = msg[:1]
        if kind == b"S":
            self.samples += 1
            self.sock.send(struct.pack(f"<{self.rig.n_in}H", *self.rig.sample()))
        elif kind == b"W" and len(msg) == _UPDATE.size + 2 * self.rig.n_out:
            _, t_us, gap_us = _UPDATE.unpack_from(msg)
            counts = struct.unpack_from(f"<{self.rig.n_out}H", msg, _UPDATE.size)
            self.rig.apply(counts)
            self.updates.append(DacUpdate(t_us, gap_us, counts))
        elif kind == b"H":
            self.sock.send(self._hello(msg))

    def _hello(self, msg: bytes) -> bytes:
        n_in, n_out = (msg[1], msg[2]) if len(msg) >= 3 else (-1, -1)
        safe = struct.unpack_from(f"<{n_out}H", msg, 3) if n_out >= 0 and len(msg) >= 3 + 2 * n_out else None
        self.layout = msg[3 + 2 * max(n_out, 0):].decode(errors="replace")
        rig = (self.rig.n_in, self.rig.n_out)
        if safe is None:
            self.refused = f"a hello of {len(msg)} bytes does not say what it carries"
        elif (n_in, n_out) != rig:
            self.refused = f"it carries {n_in} inputs and {n_out} outputs, the rig file {rig[0]} and {rig[1]}"
        elif any(abs(a - b) > 1 for a, b in zip(safe, self.safe_counts)):
            self.refused = f"its safe outputs are {list(safe)} counts, the rig file's safe_mpa {list(self.safe_counts)}"
        return b"E" + self.refused.encode() if self.refused else b"K"


def start(firmware: str, rig, link: str, *options: str,
          stdout=subprocess.PIPE) -> tuple[subprocess.Popen, FirmwarePlant]:
    """Start the firmware's host build on ``link`` with ``options`` (``--layout``,
    ``--corrupt-every``), bound to a plant of ``rig``; serve the plant (``serve``) for it to
    come up. It prints a line when it is up and its counters as JSON when it ends, to
    ``stdout`` (by default a pipe; None: this process's)."""
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    try:
        proc = subprocess.Popen([firmware, "--link", link, "--plant-fd", str(theirs.fileno()), *options],
                                pass_fds=[theirs.fileno()], stdout=stdout, text=True)
    except OSError:
        ours.close()
        raise
    finally:
        theirs.close()
    return proc, FirmwarePlant(rig, ours)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sim_backend.firmware_plant", description=__doc__.splitlines()[0])
    ap.add_argument("--firmware", required=True, help="the host build: firmware/serial-bridge/build/bridge-host")
    ap.add_argument("--config", default=None, help="rig file or built-in name (default: the simulated 2-joint rig)")
    ap.add_argument("--link", default=DEFAULT_LINK, help=f"path the daemon opens (default {DEFAULT_LINK})")
    ap.add_argument("--layout", default="cylinder-2", help="the firmware's board-table entry for the rig")
    ap.add_argument("--corrupt-every", type=int, default=0, help="flip a bit in every Nth reply (0: never)")
    args = ap.parse_args(argv)
    rig = config.load(args.config)
    proc, plant = start(args.firmware, rig, args.link, "--layout", args.layout,
                        "--corrupt-every", str(args.corrupt_every), stdout=None)
    stopping = []
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(1))
    signal.signal(signal.SIGINT, lambda *_: stopping.append(1))
    print(f"firmware plant: rig {rig.rig.name}, firmware pid {proc.pid}", flush=True)
    try:
        plant.serve(lambda: bool(stopping) or proc.poll() is not None)
    finally:
        if proc.poll() is None:
            proc.terminate()  # it prints its counters
        proc.wait(timeout=10)
        plant.sock.close()
    if plant.refused:
        print(f"firmware plant: layout {plant.layout} refused: {plant.refused}", file=sys.stderr)
    return 0 if proc.returncode == 0 and not plant.refused else 1


if __name__ == "__main__":
    sys.exit(main())
