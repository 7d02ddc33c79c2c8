"""The simulated rig served as a Modbus device (a pymodbus server whose registers the plant drives).

    python -m sim_backend.modbus_peer [--config RIG] [--port 5020] [--framer socket|rtu]
                                      [--input-address 0] [--output-address 100] [--exception-every N]

Registers follow the daemon's ``backend = "modbus"`` map: the outputs from
``--output-address`` (written by function 16 or 23) go to the simulated rig's DACs; a read
of the inputs from ``--input-address`` (function 03, 04 or 23) first steps the plant to the
present (real time) and fills them with the rig's sensor counts. ``--framer rtu`` speaks RTU
framing over the TCP socket, which the daemon reaches with ``mode = "rtu"`` and
``device = "socket://127.0.0.1:PORT"``: the RTU framing, CRC included, tested on this
machine without a serial line. ``--exception-every N`` answers every Nth read with a Modbus
exception (device busy), to exercise the host's handling of exception replies.
"""
from __future__ import annotations

import argparse
import asyncio
import signal
import sys

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from hal import config
from sim_backend.wired import WiredRig


class PlantRegisters:
    """The register action: the plant behind the registers."""

    def __init__(self, rig, input_address: int, output_address: int, exception_every: int = 0):
        self.rig = WiredRig(rig)
        self.input_address, self.output_address = input_address, output_address
        self.n_in, self.n_out = self.rig.n_in, self.rig.n_out
        self.exception_every = exception_every
        self.reads = 0

    def device(self, device_id: int) -> SimDevice:
        blocks = [SimData(self.input_address, count=self.n_in, values=0, datatype=DataType.REGISTERS),
                  SimData(self.output_address, count=self.n_out, values=0, datatype=DataType.REGISTERS)]
        return SimDevice(device_id, simdata=blocks, action=self.action)

    async def action(self, function_code, start_address, address, count, registers, set_values):
        """Called by the server for every access: a write of the outputs drives the DACs,
        a read of the inputs samples the rig into the registers first."""
        if set_values is not None and address == self.output_address:
            self.rig.apply(set_values[:self.n_out])
        elif set_values is None and address == self.input_address:
            self.reads += 1
            if self.exception_every and self.reads % self.exception_every == 0:
                return ExcCodes.DEVICE_BUSY
            offset = self.input_address - start_address
            registers[offset:offset + self.n_in] = self.rig.sample()
        return None


async def serve(args) -> None:
    rig = config.load(args.config)
    plant = PlantRegisters(rig, args.input_address, args.output_address, args.exception_every)
    framer = {"socket": FramerType.SOCKET, "rtu": FramerType.RTU}[args.framer]
    server = ModbusTcpServer(plant.device(args.device_id), framer=framer, address=(args.host, args.port))
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, lambda: asyncio.ensure_future(server.shutdown()))
    await server.serve_forever(background=True)
    print(f"modbus peer: {args.framer} framing on {args.host}:{args.port}, device {args.device_id} "
          f"(rig {rig.rig.name})", flush=True)
    await server.serving


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sim_backend.modbus_peer", description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=None, help="a simulated rig (default: the built-in one)")
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=5020)
    ap.add_argument("--framer", choices=("socket", "rtu"), default="socket")
    ap.add_argument("--device-id", type=int, default=1)
    ap.add_argument("--input-address", type=int, default=0)
    ap.add_argument("--output-address", type=int, default=100)
    ap.add_argument("--exception-every", type=int, default=0, help="answer every Nth read with an exception")
    asyncio.run(serve(ap.parse_args(argv)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
