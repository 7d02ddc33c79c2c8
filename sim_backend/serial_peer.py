"""The simulated rig as the serial bridge's peer, on a pseudo-terminal pair.

    python -m sim_backend.serial_peer [--config RIG] [--link /tmp/pneumad-bridge] [--corrupt-every N]

It makes a pty pair, points ``--link`` at the terminal end and plays the microcontroller of
docs/serial-bridge.md on the other: every outputs frame is applied to the simulated rig
(:class:`SimTransport` on the real-time clock), whose inputs come back in a frame with the
same seq. Like a real bridge it writes the rig's safe outputs when no valid frame has come
for ``safe_after_s``. ``--corrupt-every N`` flips a bit in every Nth reply, to exercise the
host's CRC handling. The daemon points at it with ``backend = "serial"`` and
``port = "/tmp/pneumad-bridge"`` (see ``pneumad --config`` and README).
"""
from __future__ import annotations

import argparse
import errno
import os
import select
import signal
import sys
import time
import tty

from hal import config
from hal import serial_frames as F
from sim_backend.wired import WiredRig

DEFAULT_LINK = "/tmp/pneumad-bridge"


class BridgePeer:
    """Answers bridge frames on ``fd`` with the simulated rig's inputs."""

    def __init__(self, rig, fd: int, safe_after_s: float = 0.02, corrupt_every: int = 0):
        self.fd = fd
        self.rig = WiredRig(rig, safe_after_s)
        self.corrupt_every = corrupt_every
        self.reader = F.FrameReader()
        self.replies = 0
        self.refused = 0  # frames of the wrong kind or channel count

    def serve(self, stop=lambda: False) -> None:
        while not stop():
            readable, _, _ = select.select([self.fd], [], [], 0.005)
            if readable:
                self._take(self._read())
            self.rig.watchdog()  # the host went quiet: the bridge's own dead-man

    def _read(self) -> bytes:
        try:
            return os.read(self.fd, 4096)
        except OSError as exc:
            if exc.errno != errno.EIO:  # EIO: no one has the terminal end open yet
                raise
            time.sleep(0.01)
            return b""

    def _take(self, data: bytes) -> None:
        for frame in self.reader.feed(data):
            if frame.kind != F.OUTPUTS or len(frame.counts) not in (0, self.rig.n_out):
                self.refused += 1
                continue
            if frame.counts:  # no counts: a query, which changes no output
                self.rig.apply(frame.counts)
            reply = bytearray(F.encode(F.INPUTS, frame.seq, self.rig.sample()))
            self.replies += 1
            if self.corrupt_every and self.replies % self.corrupt_every == 0:
                reply[-3] ^= 0x10  # a flipped bit in the payload: the host must drop it on its CRC
            os.write(self.fd, reply)


def open_pty_link(link: str) -> tuple[int, int, str]:
    """A raw pty pair and ``link`` pointing at its terminal end: (master fd, slave fd, its name)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    name = os.ttyname(slave)
    tmp = f"{link}.{os.getpid()}"
    os.symlink(name, tmp)
    os.replace(tmp, link)  # atomic: a reconnecting host never sees the link missing halfway
    return master, slave, name


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sim_backend.serial_peer", description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=None, help="rig file or built-in name (default: the simulated 2-joint rig)")
    ap.add_argument("--link", default=DEFAULT_LINK, help=f"path the daemon opens (default {DEFAULT_LINK})")
    ap.add_argument("--corrupt-every", type=int, default=0, help="flip a bit in every Nth reply (0: never)")
    args = ap.parse_args(argv)
    rig = config.load(args.config)
    master, slave, name = open_pty_link(args.link)
    peer = BridgePeer(rig, master, corrupt_every=args.corrupt_every)
    stopping = []
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(1))
    signal.signal(signal.SIGINT, lambda *_: stopping.append(1))
    print(f"serial bridge peer: {args.link} -> {name} (rig {rig.rig.name})", flush=True)
    try:
        peer.serve(lambda: bool(stopping))
    finally:
        if os.path.islink(args.link) and os.readlink(args.link) == name:
            os.unlink(args.link)
        os.close(slave)
        os.close(master)
    return 0


if __name__ == "__main__":
    sys.exit(main())
