"""Plugins the tests load through the real plugin paths (``module:Class``): a transport that
records what was written to it, and controllers that misbehave."""
from __future__ import annotations

import collections
import json
import math
import os
import sys
import threading
import time

from controllers.base import Controller
from controllers.pid import PID
from hal.schema import build
from sim_backend.options import SimOptions
from sim_backend.transport import SimTransport


class RecordingTransport(SimTransport):
    """The simulated rig, which on close() leaves its last output vectors in a JSON file
    (``[transport.options] record_to = PATH``), so a test can see what a process wrote last."""

    backend = "recording-sim"

    @classmethod
    def from_config(cls, rig, clock):
        options = dict(rig.transport.options)
        path = options.pop("record_to")
        transport = cls(rig, build(SimOptions, options, "transport.options"), clock)
        transport.record_to = path
        transport.writes = []
        # and the last 20 s of writes, each with its time [s, monotonic] and the thread that wrote it
        transport.timed = collections.deque(maxlen=20_000)
        return transport

    def _write(self, values):
        super()._write(values)
        self.writes.append(list(values))
        del self.writes[:-5]
        self.timed.append((time.monotonic(), threading.current_thread().name, list(values)))

    def close(self):
        with open(self.record_to, "w") as f:
            json.dump({"writes": self.writes, "safe_closed": True, "timed": list(self.timed)}, f)
        super().close()


class Raising(Controller):
    """Raises on its 5th step."""

    name = "raising"

    def reset(self, state, last_output):
        self.steps = 0

    def step(self, state, reference):
        self.steps += 1
        if self.steps >= 5:
            raise RuntimeError("controller bug")
        return [0.0] * self.context.n


class Contrary(Controller):
    """Commands each joint's rail furthest from what was applied the cycle before: a candidate
    as wrong as a sign error (at least half the range away from the active controller, always)."""

    name = "contrary"

    def reset(self, state, last_output):
        self.last = list(last_output)

    def applied(self, u):
        self.last = list(u)

    def step(self, state, reference):
        ctx = self.context
        return [hi if u - lo < hi - u else lo for u, lo, hi in zip(self.last, ctx.u_min, ctx.u_max)]


class ReturnsNaN(Controller):
    """Returns NaN on its 5th step."""

    name = "nan"

    def reset(self, state, last_output):
        self.steps = 0

    def step(self, state, reference):
        self.steps += 1
        return [math.nan if self.steps >= 5 else 0.0] * self.context.n


class PushesAway(Controller):
    """A controller that has lost the joint: it pushes the last joint the wrong way at its
    limit whatever the error (as a wound-up or sign-flipped controller would)."""

    name = "pushes_away"

    def reset(self, state, last_output):
        pass

    def step(self, state, reference):
        out = [0.0] * self.context.n
        out[-1] = self.context.u_max[-1] if state.angles[-1] >= reference.angles[-1] else self.context.u_min[-1]
        return out


class Slow(Controller):
    """Takes 3.5 periods of the (virtual) clock on every 100th step."""

    name = "slow"
    clock = None

    def reset(self, state, last_output):
        self.steps = 0

    def step(self, state, reference):
        self.steps += 1
        if self.steps % 100 == 0:
            self.clock.t += 3.5 * self.context.dt
        return [0.0] * self.context.n


class SlowStep(PID):
    """PID whose every step takes 5 ms of wall time more (a sleep): a lab's own controller too
    heavy for a 1 ms loop."""

    name = "slow_step"

    def step(self, state, reference):
        time.sleep(0.005)
        return super().step(state, reference)


class BiasedPID(PID):
    """The built-in PID with 0.2 V more on every output: a lab's variant of a built-in, whose own
    step the evaluation must run (not the built-in's compiled twin)."""

    name = "biased_pid"

    def step(self, state, reference):
        return [min(u + 0.2, hi) for u, hi in zip(super().step(state, reference), self.u_hi)]


HANG_S = 3.0  # how long a hanging step takes [s]
HANG_AFTER_STEPS = 500  # ... and when it comes (0.5 s after enable at 1 kHz)


class _HangsOnce(PID):
    """PID whose step hangs once for ``HANG_S``, at its ``HANG_AFTER_STEPS``-th step; when it
    begins, the time [s, monotonic] is written to the file ``$PNEUMAD_TEST_HANG_MARK`` names."""

    def step(self, state, reference):
        self.steps = getattr(self, "steps", 0) + 1
        if self.steps == HANG_AFTER_STEPS:
            mark = os.environ.get("PNEUMAD_TEST_HANG_MARK")
            if mark:
                with open(mark, "w") as f:
                    f.write(repr(time.monotonic()))
            self.hang()
        return super().step(state, reference)


class SleepsHung(_HangsOnce):
    """Its step sleeps (the GIL released, as for blocking I/O)."""

    name = "sleeps_hung"

    def hang(self):
        time.sleep(HANG_S)


class SpinsHung(_HangsOnce):
    """Its step busy-loops in Python (the GIL taken back every switch interval)."""

    name = "spins_hung"

    def hang(self):
        end = time.monotonic() + HANG_S
        while time.monotonic() < end:
            pass


class _BuildsBadly(Controller):
    """Never reaches the loop: its build misbehaves in the worker process."""

    def reset(self, state, last_output):
        pass

    def step(self, state, reference):
        return [0.0] * self.context.n


class DiesWhenBuilt(_BuildsBadly):
    """Its build kills the process that builds it, as a crash in a native library would."""

    name = "dies"

    def derive(self, values):
        os._exit(3)


class HangsWhenBuilt(_BuildsBadly):
    """Its build never finishes."""

    name = "hangs"

    def derive(self, values):
        time.sleep(3600)


class SlowToBuild(_BuildsBadly):
    """Its build takes longer than a one-shot command's lease (pneumactl's 10 s), then refuses."""

    name = "slow_to_build"

    def derive(self, values):
        time.sleep(12.0)
        raise ValueError("slow_to_build: took its time, and refuses")


class UnsendableWhenBuilt(_BuildsBadly):
    """Its design holds something that cannot leave the process it was made in."""

    name = "unsendable"

    def derive(self, values):
        return lambda: None


def imported(module: str) -> bool:
    """Whether ``module`` was ever imported in this process (asked of a worker by a test)."""
    return module in sys.modules


class LabPDFF(PID):
    """A lab's own controller, as a plugin reached by its module path: the PID under a name of
    its own (what ``pneumactl evaluate`` and the robustness bench take beside the built-ins)."""

    name = "lab_pdff"
