"""Modbus I/O modules, TCP or RTU, through pymodbus (the only module here that imports it).

The register map and scaling are in the rig file (``backend = "modbus"``): the inputs, in the
order of :func:`hal.transport.rig_channels`, are consecutive registers from
``input_address``; the outputs from ``output_address``. A raw count maps linearly onto the
channel's span: 0 at its low end, ``full_scale_counts`` at its high end.

One exchange is one read-write transaction (function 23: write the outputs, read the inputs,
both holding registers) where the module supports it (``read_write = true``), else a write
(16) and a read (04, input registers). It runs in its own process (:mod:`hal.offloop`), so
a slow round trip never stalls a cycle; TCP_NODELAY is set on the TCP socket.

pymodbus changes its API between minor versions (``slave`` became ``device_id``; the server's
datastores were replaced by SimData/SimDevice); pyproject.toml pins the range this adapter
and the simulated server were written and tested against.
"""
from __future__ import annotations

import socket
from collections.abc import Sequence
from dataclasses import dataclass

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.framer import FramerType

from hal.offloop import BadReply, Link, LinkDown, LinkTimeout, OffLoopTransport
from hal.schema import build, require
from hal.transport import rig_channels, safe_outputs


@dataclass(frozen=True)
class ModbusOptions:
    """``[transport.options]`` when ``backend = "modbus"``."""

    mode: str = "tcp"  # "tcp", or "rtu" (RTU framing on a serial line, or on socket://HOST:PORT)
    host: str = "127.0.0.1"  # tcp
    port: int = 502  # tcp
    device: str = ""  # rtu: /dev/ttyUSB0, or a pyserial URL such as socket://127.0.0.1:5021
    baudrate: int = 115200  # rtu
    device_id: int = 1
    input_address: int = 0
    output_address: int = 100
    full_scale_counts: int = 65535
    read_write: bool = True  # one function-23 transaction per exchange
    timeout_s: float = 0.05  # one transaction
    rate_hz: float = 1000.0  # exchanges per second the worker attempts
    open_timeout_s: float = 5.0  # the first sample must arrive within this
    reopen_every_s: float = 0.5  # after the link is lost, try again this often
    worker_priority: int = 0  # SCHED_FIFO priority of the worker process (0: normal scheduling)

    def __post_init__(self):
        require(self.mode in ("tcp", "rtu"), "mode", "must be tcp or rtu")
        require(self.mode != "rtu" or bool(self.device), "device", "rtu needs a serial device or socket:// URL")
        require(0 < self.port < 65536, "port", "must be a TCP port")
        require(0 <= self.device_id <= 247, "device_id", "must be within 0-247")
        require(0 <= self.input_address < 65536 and 0 <= self.output_address < 65536, "input_address",
                "register addresses must be within 0-65535")
        require(0 < self.full_scale_counts <= 65535, "full_scale_counts", "must be within 1-65535")
        require(0 < self.timeout_s <= 5, "timeout_s", "must be within (0, 5] s")
        require(0 < self.rate_hz <= 10000, "rate_hz", "must be within (0, 10000] Hz")
        require(0 < self.open_timeout_s <= 60, "open_timeout_s", "must be within (0, 60] s")
        require(0 < self.reopen_every_s <= 60, "reopen_every_s", "must be within (0, 60] s")
        require(0 <= self.worker_priority <= 98, "worker_priority", "must be within 0-98")


class ModbusLink(Link):
    """The thin adapter over pymodbus's synchronous client."""

    def __init__(self, options: ModbusOptions, n_in: int):
        self.o, self.n_in = options, n_in
        if options.mode == "tcp":
            self.client = ModbusTcpClient(options.host, port=options.port, timeout=options.timeout_s, retries=0)
        else:
            self.client = ModbusSerialClient(options.device, framer=FramerType.RTU, baudrate=options.baudrate,
                                             timeout=options.timeout_s, retries=0)

    def where(self) -> str:
        return f"{self.o.host}:{self.o.port}" if self.o.mode == "tcp" else self.o.device

    def connect(self) -> None:
        if not self.client.connect():
            raise LinkDown(f"cannot connect to {self.where()}")
        sock = getattr(self.client, "socket", None)
        if self.o.mode == "tcp" and isinstance(sock, socket.socket):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def exchange(self, outputs: Sequence[int]) -> Sequence[int]:
        o = self.o
        try:
            if o.read_write:
                reply = self.client.readwrite_registers(read_address=o.input_address, read_count=self.n_in,
                                                        write_address=o.output_address, values=[int(v) for v in outputs],
                                                        device_id=o.device_id)
            else:
                written = self.client.write_registers(o.output_address, [int(v) for v in outputs], device_id=o.device_id)
                if written.isError():
                    raise BadReply(f"write refused by {self.where()}: {written}", "exception_replies")
                reply = self.client.read_input_registers(o.input_address, count=self.n_in, device_id=o.device_id)
        except (ConnectionException, OSError) as exc:  # pymodbus lets a reset socket's OSError through
            raise LinkDown(f"connection to {self.where()} lost: {exc}") from None
        except ModbusIOException as exc:
            raise LinkTimeout(f"no reply from {self.where()} within {o.timeout_s:g} s: {exc}") from None
        except ModbusException as exc:
            raise BadReply(f"bad reply from {self.where()}: {exc}") from None
        if reply.isError():
            raise BadReply(f"{self.where()} answered with an exception: {reply}", "exception_replies")
        registers = reply.registers
        if len(registers) != self.n_in:
            raise BadReply(f"{self.where()} returned {len(registers)} registers, {self.n_in} asked for")
        return registers

    def close(self) -> None:
        self.client.close()


def make_link(options: ModbusOptions, n_in: int) -> ModbusLink:
    return ModbusLink(options, n_in)


class ModbusTransport(OffLoopTransport):
    backend = "modbus"

    def __init__(self, rig, options: ModbusOptions, clock):
        self.options = options
        self.inputs, self.outputs, _ = rig_channels(rig)
        self.full_scale = options.full_scale_counts
        super().__init__(clock, options.rate_hz, options.open_timeout_s, options.reopen_every_s,
                         options.worker_priority, safe_outputs(rig))

    @classmethod
    def from_config(cls, rig, clock):
        return cls(rig, build(ModbusOptions, rig.transport.options, "transport.options"), clock)

    def link_factory(self):
        return make_link, (self.options, len(self.inputs))
