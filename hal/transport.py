"""The transport contract: one small interface every DAQ backend implements.

A transport moves raw channel values (volts, 0/1 for digital lines) in and out, one sweep
each way per cycle. It declares its channels up front so the rig configuration can be
checked against it before anything moves. Values cross the contract as plain tuples of
floats in the declared channel order, so the 1 ms path allocates no per-channel objects.

Backends are plugins, named in the rig file (``transport.backend``): a class registered under
the entry-point group ``pneumad.transports`` (the built-ins, ``sim``, ``serial``, ``modbus``,
``can``, in pneumad's pyproject.toml; a lab's in its own package's), or a ``module:Class`` path.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import Enum

from hal import sensors
from hal.errors import CommandError, ConfigError
from hal.plugins import load_entry_point

GROUP = "pneumad.transports"


class ChannelKind(str, Enum):
    ANALOG_IN = "ai"
    ANALOG_OUT = "ao"
    DIGITAL_IN = "di"
    DIGITAL_OUT = "do"


@dataclass(frozen=True)
class Channel:
    """One raw channel: its name in the rig file, its kind and its electrical range [V]."""

    name: str
    kind: ChannelKind
    low: float = 0.0
    high: float = 10.0

    @property
    def is_input(self) -> bool:
        return self.kind in (ChannelKind.ANALOG_IN, ChannelKind.DIGITAL_IN)


@dataclass(slots=True)
class InputSweep:
    """All inputs from one read: values in declared order and when they were sampled."""

    seq: int  # the transport's sample counter; a repeat means no new sample
    t: float  # sample time on the loop's clock [s]
    values: tuple[float, ...]


@dataclass
class TransportHealth:
    """Counters a supervisor and an operator can read; never hidden, never reset silently."""

    is_open: bool = False
    reads: int = 0
    writes: int = 0
    errors: int = 0
    last_error: str = ""
    last_sample_t: float = math.nan
    counters: dict[str, int] = field(default_factory=dict)  # backend-specific (e.g. crc_errors)


class Transport(ABC):
    """A DAQ backend. Subclasses set ``inputs``/``outputs``/``rate_hz`` and implement the sweeps."""

    backend: str = "abstract"
    inputs: tuple[Channel, ...] = ()
    outputs: tuple[Channel, ...] = ()
    rate_hz: float = 1000.0  # the sweep rate the backend can sustain
    open_timeout_s: float = 1.0  # how long the rig may take to answer, at opening and at the loop's start [s]

    def __init__(self):
        self._health = TransportHealth()

    @classmethod
    def from_config(cls, rig, clock: Callable[[], float]) -> "Transport":
        """Build from a :class:`hal.config.RigConfig`; backends validate ``rig.transport.options``.
        Building touches no wire (``pneumad --check`` builds and never opens): :meth:`open` does."""
        raise NotImplementedError(f"{cls.__name__} cannot be built from a rig file")

    def open(self) -> None:
        self._health.is_open = True

    def close(self) -> None:
        self._health.is_open = False

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        self.close()

    @abstractmethod
    def read(self) -> InputSweep:
        """Sample every input once. Raises :class:`hal.errors.TransportError` on failure."""

    def write(self, values: Sequence[float]) -> None:
        """Write every output once, in declared order; a bad vector is refused whole."""
        if len(values) != len(self.outputs):
            raise CommandError(f"{self.backend}: expected {len(self.outputs)} output values, got {len(values)}")
        for ch, v in zip(self.outputs, values):
            if not (ch.low <= v <= ch.high):  # also false for NaN
                raise CommandError(f"{self.backend}: output {ch.name} = {v!r} is outside {ch.low}..{ch.high} V")
        self._write(values)
        self._health.writes += 1

    @abstractmethod
    def _write(self, values: Sequence[float]) -> None:
        """Backend part of :meth:`write`; the values are already checked."""

    def health(self) -> TransportHealth:
        return self._health

    def check_worker(self) -> str | None:
        """A transport with a process of its own (hal.offloop) starts it again if it died,
        never waiting; what happened, as an event's cause. None: nothing happened (or no process)."""
        return None

    def worker_health(self) -> dict | None:
        """That process as of the last check (hal.process.Helper.health); None without one."""
        return None

    def index(self, name: str, *, output: bool) -> int:
        """Position of channel ``name`` in the input or output sweep."""
        channels = self.outputs if output else self.inputs
        for i, ch in enumerate(channels):
            if ch.name == name:
                return i
        kind = "output" if output else "input"
        names = ", ".join(ch.name for ch in channels) or "none"
        raise ConfigError(f"{self.backend}: no {kind} channel named {name!r} (it has: {names})")


FULL_SCALE_COUNTS = 0xFFFF  # the top count of a 16-bit converter


def volts_to_counts(values: Sequence[float], channels: Sequence[Channel],
                    full_scale: int = FULL_SCALE_COUNTS) -> list[int]:
    """Raw counts for a wire, linear over each channel's span: 0 at its low end, ``full_scale``
    at its high end (clipped to that range)."""
    return [min(max(round((v - ch.low) / (ch.high - ch.low) * full_scale), 0), full_scale)
            for v, ch in zip(values, channels)]


def counts_to_volts(counts: Sequence[int], channels: Sequence[Channel],
                    full_scale: int = FULL_SCALE_COUNTS) -> tuple[float, ...]:
    """Volts from a wire's raw counts: the inverse of :func:`volts_to_counts`."""
    return tuple(ch.low + c * (ch.high - ch.low) / full_scale for c, ch in zip(counts, channels))


def rig_channels(rig) -> tuple[tuple[Channel, ...], tuple[Channel, ...], tuple]:
    """The channels a rig file names, in the order every built-in transport carries them:
    inputs are each joint's position sensor, each joint's further sensors (chamber transmitters,
    inputs), each distinct supply a ratiometric sensor reads, then the rig's sensors (force,
    supply pressure, inputs) (:mod:`hal.sensors`); outputs are each joint's in its own order (head,
    rod; valve a, valve b, brake; a 5/3 valve). Also what each input is: its
    :class:`hal.sensors.Placed`, or None for a supply channel."""
    placed = sensors.positions(rig) + sensors.measured(rig)
    joints = [p for p in placed if p.joint >= 0]
    order = joints + [None] * len(rig.supply_channels()) + [p for p in placed if p.joint < 0]
    names = [p.config.channel for p in joints] + rig.supply_channels() + [p.config.channel for p in placed
                                                                          if p.joint < 0]
    inputs = tuple(Channel(name, ChannelKind.ANALOG_IN, 0.0, 10.0) for name in names)
    outputs = tuple(Channel(channel, ChannelKind.ANALOG_OUT, 0.0, 10.0)
                    for j in rig.joints for _, channel in j.output_channels())
    return inputs, outputs, tuple(order)


def safe_outputs(rig) -> tuple[float, ...]:
    """The rig's safe state as an output sweep [V] (:func:`rig_channels`' order): what a transport
    that writes before the loop does (a Modbus worker's first exchange) writes."""
    return tuple(v for j in rig.joints for v in j.safe_volts())


def load_backend(name: str) -> type[Transport]:
    """The transport class registered as ``name`` (entry-point group ``pneumad.transports``) or
    at a ``module:Class`` path; a ConfigError naming ``transport.backend`` otherwise, with the
    plugin's own error if it fails to import."""
    try:
        return load_entry_point(name, GROUP, Transport, "backend")
    except LookupError as exc:
        raise ConfigError(f"transport.backend: {exc}") from None


def create_transport(rig, clock: Callable[[], float]) -> Transport:
    """Build the transport the rig file names, with its backend options validated."""
    return load_backend(rig.transport.backend).from_config(rig, clock)
