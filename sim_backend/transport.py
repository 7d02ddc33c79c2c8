"""The simulated rig behind the transport contract: volts in, volts out, on a clock.

Each :meth:`SimTransport.read` first advances the plant to the clock's present time in
whole plant steps, then samples the sensors; each write does the same before the new outputs
take effect, so a command acts from when it arrives, never from the read before it (behind a
wire the two can be milliseconds apart, which would otherwise shorten the plant's dead time). Handed a virtual clock, the plant runs in
lockstep with the loop (deterministic, faster than real time); handed ``time.monotonic``,
it runs in real time. Sensor volts come from the rig file's own calibrations read
backwards, plus seeded noise and ADC quantisation; output volts go through DAC quantisation.

In real time the plant can step beside the loop instead (``beside_loop``; by default when the
loop runs at a real-time priority): a thread of the loop's process advances it and leaves the
latest sweep for the loop's read
(:mod:`sim_backend.plant_thread`), as a DAQ samples on its own processor; outputs written
in between take effect from when they were written, as in lockstep.

The plant is the rig's kind: the planar arm of regulator-driven rotary joints
(:mod:`sim_backend.plant`), the muscle joint (:mod:`sim_backend.muscle_plant`), or linear axes on
5/3 valves (:mod:`sim_backend.axis_plant`). Every sensor the rig file names reads the plant's
truth through its own calibration (positions, chamber and supply pressures, the tip force); a
further input the plant has no model of reads the middle of its plausible range.

Faults can be injected to exercise the supervisor: a disconnected sensor (reads the 0 V
rail), a stuck sensor, a noise burst, a transport timeout, and loss of supply pressure.
"""
from __future__ import annotations

import math
import os
import random
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence

from hal.config import RigConfig
from hal.devices import Ratiometric
from hal.directional_valve import DirectionalValve
from hal.errors import ConfigError, TransportError, TransportTimeout
from hal.interfaces import LINEAR, ROTARY
from hal.joints import CYLINDER, MUSCLE_PAIR, VALVE
from hal.schema import build
from hal.sensors import Placed
from hal.transport import InputSweep, Transport, rig_channels
from sim_backend.axis_plant import SimAxisRig
from sim_backend.muscle_plant import SimMuscleRig
from sim_backend.options import SimOptions
from sim_backend.plant import SimArm
from sim_backend.plant_thread import PlantThread

FAULTS = ("disconnect", "stuck", "noise_burst", "timeout", "supply_lost")
LATE_STEPS = 1.5  # beside the loop: a sweep older than this many plant steps is taken in the read instead
WRITES_KEPT = 64  # beside the loop: outputs waiting for a tick (1-2 normally; bounded if its thread failed)


def real_time_priority() -> bool:
    """Whether the calling thread runs at a real-time policy (SCHED_FIFO or SCHED_RR)."""
    return os.sched_getscheduler(0) in (os.SCHED_FIFO, os.SCHED_RR)


def converter(low: float, high: float, bits: int) -> tuple[float, float, float]:
    """(low, high, lsb) [V] of a converter with ``bits`` over ``low..high``: what
    :func:`quantise` takes, worked out once rather than every sample."""
    return low, high, (high - low) / ((1 << bits) - 1)


def quantise(value: float, low: float, high: float, lsb: float) -> float:
    """The value a converter over ``low..high`` [V] with step ``lsb`` represents (clipped)."""
    return low + round(((low if value < low else high if value > high else value) - low) / lsb) * lsb


def linear(volts_for) -> tuple[float, float]:
    """(offset [V], slope [V per unit]) of a sensor read backwards, ``volts_for(quantity)``,
    which is linear: the sensor's own calibration, evaluated once rather than every sample."""
    offset = volts_for(0.0)
    return offset, volts_for(1.0) - offset


def plant_for(rig: RigConfig, options: SimOptions):
    """The plant of the rig's kind (module docstring); ConfigError for a rig the simulator has
    no model of."""
    kinds = {(j.kind, j.actuation) for j in rig.joints}
    if kinds == {(ROTARY, CYLINDER)} and options.compiled:
        from sim_backend.compiled_plant import CompiledArm  # numba: imported only when asked for
        return CompiledArm(rig, options)
    if kinds == {(ROTARY, CYLINDER)}:
        return SimArm(rig, options)
    if options.compiled:
        raise ConfigError("transport.options.compiled: only the planar arm of cylinder joints has a compiled plant; "
                          "this rig's runs on the Python one (set compiled = false)")
    if kinds == {(ROTARY, MUSCLE_PAIR)}:
        return SimMuscleRig(rig, options)
    if kinds == {(LINEAR, VALVE)}:
        return SimAxisRig(rig, options)
    raise ConfigError("transport.backend: the simulator models a planar arm of rotary joints on regulator pairs, "
                      "a muscle-pair joint, or linear joints on 5/3 valves; this rig has "
                      + ", ".join(sorted(f"{kind} joints on {actuation}" for kind, actuation in kinds)))


def initial_outputs(rig: RigConfig) -> list[float]:
    """What the DACs drive before the first write [V]: a regulator pair its biases, a muscle
    pair's valves and brake 0 V (vented, released), a 5/3 valve its safe command."""
    out = []
    for j in rig.joints:
        if j.actuation == CYLINDER:
            out += [j.head.bias_volts, j.rod.bias_volts]
        elif j.actuation == VALVE:
            out.append(DirectionalValve(j.valve).safe_volts)
        else:
            out += [0.0] * len(j.output_channels())
    return out


class SimTransport(Transport):
    backend = "sim"
    rate_hz = 1000.0

    def __init__(self, rig: RigConfig, options: SimOptions, clock: Callable[[], float], beside: str = "never"):
        """``beside`` (real time only): step the plant in a thread of its own from the first read,
        ``"always"`` or when that read runs at a real-time priority (``"realtime"``)."""
        super().__init__()
        self.options = options
        self.clock = clock
        self.arm = plant_for(rig, options)  # the plant, whatever the rig's kind
        self._advance_many = getattr(self.arm, "advance", None)  # the compiled plant: a catch-up in one call
        self._supply_pa = self.arm.supply_pa  # [Pa gauge] restored when a lost supply comes back
        self._rng = random.Random(options.seed)
        self._vsup = options.supply_volts
        self.inputs, self.outputs, self._sources = rig_channels(rig)
        self._out = initial_outputs(rig)
        self._adc = [converter(ch.low, ch.high, options.adc_bits) for ch in self.inputs]
        self._dac = [converter(ch.low, ch.high, options.dac_bits) for ch in self.outputs]
        self._sensing = [self._sensed(placed) for placed in self._sources]
        self._faults: dict[tuple[str, str], dict] = {}
        self._last = [0.0] * len(self.inputs)
        self._seq = 0
        self._t0 = clock()
        self._steps = 0
        self._next_step_t = self._t0 + self.options.step_s * (1.0 - 1e-6)  # when another plant step is due [s]
        # Beside the loop: the plant's lock (its thread, an in-cycle catch-up, fault injection),
        # the outputs written since its last tick with their times, and its latest sweep.
        self._beside = beside != "never"
        self._beside_needs_rt = beside == "realtime"
        self._thread: PlantThread | None = None
        self._lock = threading.Lock()
        self._written: deque[tuple[tuple[float, ...], float]] = deque(maxlen=WRITES_KEPT)
        self._wrote_at = self._t0
        self._latest: InputSweep | None = None
        self._read_seq = 0  # the last sweep a read returned

    @classmethod
    def from_config(cls, rig: RigConfig, clock: Callable[[], float]) -> "SimTransport":
        """On the real-time clock (``time.monotonic``, what the daemon's loop runs on) the plant
        steps beside the loop as ``beside_loop`` says; on a virtual clock, in lockstep."""
        options = build(SimOptions, rig.transport.options, "transport.options")
        return cls(rig, options, clock, beside=options.beside_loop if clock is time.monotonic else "never")

    def close(self) -> None:
        """Stop the plant's thread; the outputs written last (the safe state, at shutdown) take effect."""
        if self._thread is not None:
            self._thread.close()
            if self._thread.failure is None:
                self.tick()
        super().close()

    # -- the sweeps ---------------------------------------------------------------------
    def read(self) -> InputSweep:
        if ("timeout", "") in self._faults:
            self._health.errors += 1
            self._health.last_error = "simulated transport timeout"
            raise TransportTimeout("sim: simulated transport timeout (injected fault)")
        if self._beside and self._thread is None and self._beside_needs_rt and not real_time_priority():
            self._beside = False  # a thread that cannot take the loop's real-time priority would not keep pace
        if self._beside:
            sweep = self._beside_sweep()
        else:
            now = self.clock()
            self._advance(now)
            sweep = self._sweep(now)
        self._health.reads += 1
        self._health.last_sample_t = sweep.t
        return sweep

    def _sweep(self, now: float) -> InputSweep:
        self._seq += 1
        return InputSweep(self._seq, now, self._sample())

    def _beside_sweep(self) -> InputSweep:
        """The plant thread's latest sweep, a new one at every read and never more than
        ``LATE_STEPS`` old: the first read starts the thread (so it takes the reader's
        scheduling), and when the thread has not ticked since the last read or its sweep is
        older (the thread held up by a loaded machine, or the loop overran, or both held up
        and the loop first to run again) the read ticks the plant itself."""
        thread = self._thread
        if thread is None:
            self.tick()
            self._thread = PlantThread(self.tick, self.options.step_s, self.clock, lambda: self._wrote_at)
            self._thread.start()
        elif thread.failure is not None:
            raise TransportError(f"sim: the plant's thread failed: {type(thread.failure).__name__}: {thread.failure}")
        elif self._behind() and self._lock.acquire(timeout=self.options.step_s):
            try:  # the thread mid-tick: at most a tick's wait; held up: its tick, here
                if self._behind():
                    self._tick_locked()
                    counters = self._health.counters
                    counters["plant_ticks_in_cycle"] = counters.get("plant_ticks_in_cycle", 0) + 1
            finally:
                self._lock.release()
        sweep = self._latest
        self._read_seq = sweep.seq
        return sweep

    def _behind(self) -> bool:
        latest = self._latest
        return latest.seq == self._read_seq or self.clock() - latest.t > LATE_STEPS * self.options.step_s

    def tick(self) -> None:
        """Beside the loop: take the outputs written since the last tick, each from when it was
        written, step the plant to the present and leave a fresh sweep."""
        with self._lock:
            self._tick_locked()

    def _tick_locked(self) -> None:
        written = self._written
        while written:
            values, t = written.popleft()
            if t >= self._next_step_t:
                self._advance(t)
            self._drive(values)
        now = self.clock()
        self._advance(now)
        self._latest = self._sweep(now)

    def _write(self, values: Sequence[float]) -> None:
        if ("timeout", "") in self._faults:
            self._health.errors += 1
            raise TransportTimeout("sim: simulated transport timeout (injected fault)")
        now = self.clock()
        if self._thread is not None:  # the plant's thread takes it in from its time
            self._written.append((tuple(values), now))
            self._wrote_at = now
            return
        if now >= self._next_step_t:  # the common case in process: the read of this cycle brought it up to date
            self._advance(now)
        self._drive(values)

    def _drive(self, values: Sequence[float]) -> None:
        """The DACs take ``values`` [V], quantised."""
        self._out = [quantise(v, *dac) for v, dac in zip(values, self._dac)]

    @property
    def output_volts(self) -> tuple[float, ...]:
        """What the simulated DAC is driving now (what a scope on the outputs would show)."""
        return tuple(self._out)

    def _advance(self, now: float) -> None:
        h = self.options.step_s
        due = int((now - self._t0) / h + 1e-6) - self._steps
        limit = int(self.options.max_catch_up_s / h)
        if due > limit:  # a stall in real-time mode: pause the plant rather than block the loop
            self._health.counters["plant_steps_skipped"] = self._health.counters.get("plant_steps_skipped", 0) + due - limit
            self._steps += due - limit
            due = limit
        if self._advance_many is None:
            for _ in range(due):
                self.arm.step(self._out)
        elif due > 0:
            self._advance_many(self._out, due)
        self._steps += max(due, 0)
        self._next_step_t = self._t0 + h * (self._steps + 1 - 1e-6)

    def _sensed(self, placed: Placed | None) -> tuple[str, int, float, float]:
        """How an input reads the plant: (quantity, joint, offset [V], slope [V per SI unit]),
        from the rig file's calibrations read backwards (all linear). A supply channel reads
        the potentiometers' supply; an input the plant has no model of, its range's middle."""
        if placed is None:
            return ("supply", 0, self._vsup, 0.0)
        sensor, name = placed.sensor, placed.name
        if isinstance(sensor, Ratiometric):
            offset, slope = linear(lambda x: self._vsup * sensor.ratio_for(x))
        else:
            offset, slope = linear(sensor.volts_for)
        if name == "position":
            return ("position", placed.joint, offset, slope)
        if placed.owner and name in ("p_head", "p_a", "p_rod", "p_b"):
            return ("second" if name in ("p_rod", "p_b") else "first", placed.joint, offset, slope)
        if not placed.owner and name in ("force", "supply_pressure"):
            return (name, 0, offset, slope)
        low, high = sensor.low, sensor.high
        middle = 0.5 * (low + high) if math.isfinite(low) and math.isfinite(high) else 0.0
        return ("constant", 0, offset + slope * middle, 0.0)

    def _sample(self) -> tuple[float, ...]:
        arm, gauss, sigma = self.arm, self._rng.gauss, self.options.adc_noise_volts
        faults = self._faults
        out = []
        for idx, ((what, i, offset, slope), adc) in enumerate(zip(self._sensing, self._adc)):
            if what == "position":
                v = offset + slope * arm.sensed_position(i)
            elif what == "first" or what == "second":
                v = offset + slope * arm.chamber_gauge(i, what == "second")
            elif what == "force":
                v = offset + slope * arm.contact_force_n
            elif what == "supply_pressure":
                v = offset + slope * arm.supply_pa
            else:  # a supply channel, a constant
                v = offset
            s = sigma
            if faults:
                fault_v, s = self._apply_faults(self.inputs[idx].name, idx, v, s)
                if fault_v is not None:
                    out.append(fault_v)
                    continue
            if s > 0.0:
                v += gauss(0.0, s)
            out.append(quantise(v, *adc))
        self._last = out
        return tuple(out)

    def _apply_faults(self, channel: str, idx: int, v: float, sigma: float) -> tuple[float | None, float]:
        if ("disconnect", channel) in self._faults:
            return 0.0, sigma
        if ("stuck", channel) in self._faults:
            return self._faults[("stuck", channel)]["value"], sigma
        burst = self._faults.get(("noise_burst", channel))
        if burst is not None:
            burst["samples"] -= 1
            if burst["samples"] <= 0:
                del self._faults[("noise_burst", channel)]
            return None, math.hypot(sigma, burst["sigma_volts"])
        return None, sigma

    # -- fault injection ----------------------------------------------------------------
    def inject(self, fault: str, channel: str = "", *, sigma_volts: float = 1.0, samples: int = 10) -> None:
        """Start a fault: ``disconnect``/``stuck``/``noise_burst`` on an input ``channel``, or
        ``timeout``/``supply_lost`` on the whole rig."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r} (known: {', '.join(FAULTS)})")
        per_channel = fault in ("disconnect", "stuck", "noise_burst")
        if per_channel:
            names = [ch.name for ch in self.inputs]
            if channel not in names:
                raise ConfigError(f"sim: no input channel {channel!r} to fault (inputs: {', '.join(names)})")
        else:
            channel = ""
        state: dict = {}
        with self._lock:  # the plant's thread samples under it
            if fault == "stuck":
                state["value"] = self._last[[ch.name for ch in self.inputs].index(channel)]
            elif fault == "noise_burst":
                state.update(sigma_volts=sigma_volts, samples=samples)
            elif fault == "supply_lost":
                self.arm.supply_pa = 0.0
            self._faults[(fault, channel)] = state

    def clear(self, fault: str | None = None) -> None:
        """End one kind of fault (every channel), or all faults."""
        with self._lock:
            for key in [k for k in self._faults if fault in (None, k[0])]:
                del self._faults[key]
            if fault in (None, "supply_lost"):
                self.arm.supply_pa = self._supply_pa
