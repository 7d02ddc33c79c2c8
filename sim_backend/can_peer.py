"""The simulated rig as a CAN I/O node (python-can), the frames of :mod:`hal.can_bus`.

    python -m sim_backend.can_peer [--config RIG] [--interface udp_multicast] [--channel 239.74.163.2]
                                   [--wrong-id-every N] [--short-frame-every N]

Output frames drive the simulated rig's DACs (real time); each complete set is answered
with the input frames. After ``safe_after_s`` without output frames it writes the rig's
safe outputs, as a real node's watchdog would. ``--wrong-id-every N`` also sends a frame
with an id nobody uses every N answers, ``--short-frame-every N`` an input frame one byte
short, to exercise the host's counting. On one machine,
``udp_multicast`` joins the daemon across processes; ``virtual`` works inside one process
(see :class:`CanPeer`, which the tests run in a thread).
"""
from __future__ import annotations

import argparse
import signal
import struct
import sys

import can

from hal import config
from hal.can_bus import PER_FRAME, bus_port, frame_ids, pack
from sim_backend.wired import WiredRig

DEFAULT_GROUP = "239.74.163.2"  # python-can's IPv4 default group for udp_multicast


class CanPeer:
    def __init__(self, rig, bus: can.BusABC, output_id: int = 0x200, input_id: int = 0x180,
                 safe_after_s: float = 0.02, wrong_id_every: int = 0, short_frame_every: int = 0):
        self.bus = bus
        self.rig = WiredRig(rig, safe_after_s)
        self.out_ids = frame_ids(output_id, self.rig.n_out)
        self.in_ids = frame_ids(input_id, self.rig.n_in)
        self.wrong_id_every = wrong_id_every
        self.short_frame_every = short_frame_every
        self._counts = [0] * self.rig.n_out
        self.answers = 0

    def serve(self, stop=lambda: False) -> None:
        while not stop():
            msg = self.bus.recv(timeout=0.005)
            if msg is not None and msg.arbitration_id in self.out_ids and not msg.is_extended_id:
                self._take(msg)
            self.rig.watchdog()

    def _take(self, msg: can.Message) -> None:
        index = msg.arbitration_id - self.out_ids.start
        last = index == len(self.out_ids) - 1
        if msg.dlc == 0:  # a query: answer, change nothing
            self._answer()
            return
        n = min(PER_FRAME, len(self._counts) - PER_FRAME * index)
        if msg.dlc != 2 * n:
            return
        self._counts[PER_FRAME * index:PER_FRAME * index + n] = struct.unpack(f"<{n}H", bytes(msg.data))
        if last:
            self.rig.apply(self._counts)
            self._answer()

    def _answer(self) -> None:
        for arbitration_id, data in zip(self.in_ids, pack(self.rig.sample())):
            self.bus.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))
        self.answers += 1
        if self.wrong_id_every and self.answers % self.wrong_id_every == 0:
            self.bus.send(can.Message(arbitration_id=0x7E5, data=b"\x00" * 8, is_extended_id=False))
        if self.short_frame_every and self.answers % self.short_frame_every == 0:
            self.bus.send(can.Message(arbitration_id=self.in_ids.start, data=b"\x00" * 7, is_extended_id=False))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sim_backend.can_peer", description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=None, help="a simulated rig (default: the built-in one)")
    ap.add_argument("--interface", default="udp_multicast")
    ap.add_argument("--channel", default=DEFAULT_GROUP)
    ap.add_argument("--port", type=int, default=None, help="udp_multicast's UDP port (default: python-can's)")
    ap.add_argument("--output-id", type=lambda s: int(s, 0), default=0x200)
    ap.add_argument("--input-id", type=lambda s: int(s, 0), default=0x180)
    ap.add_argument("--wrong-id-every", type=int, default=0)
    ap.add_argument("--short-frame-every", type=int, default=0)
    args = ap.parse_args(argv)
    rig = config.load(args.config)
    bus = can.Bus(interface=args.interface, channel=args.channel, **bus_port(args.port))
    peer = CanPeer(rig, bus, args.output_id, args.input_id, wrong_id_every=args.wrong_id_every,
                   short_frame_every=args.short_frame_every)
    stopping = []
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(1))
    signal.signal(signal.SIGINT, lambda *_: stopping.append(1))
    print(f"can peer: {args.interface} channel {args.channel}, outputs from {args.output_id:#x}, "
          f"inputs from {args.input_id:#x} (rig {rig.rig.name})", flush=True)
    try:
        peer.serve(lambda: bool(stopping))
    finally:
        bus.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
