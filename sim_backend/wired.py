"""The simulated rig as an I/O node on a wire sees it: raw counts in and out, on the
real-time clock, and the node's own watchdog. Shared by the peers behind each transport
(serial_peer, modbus_peer, can_peer).

A real node samples when a request comes; the host stamps the sample with the request's
send time. A peer process held by a busy machine answers late, and a plant that caught up
the whole hold at once would put a jump of seconds between two replies the host stamped a
millisecond apart: an impossible speed, and a false over-speed trip (seen beside two CPU
hogs: 823 deg/s on the muscle rig). So the peer's plant catches up at most ``CATCH_UP_S``
at a time and otherwise pauses with the peer, as the in-process simulator does for the
loop's own stalls (``max_catch_up_s``). Through the loop's 10 Hz velocity filter a 20 ms
jump of a joint moving at 10 deg/s (the paths) reads as about 22 deg/s for a moment, well
inside the cylinder rig's 60 deg/s limit."""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence

from hal.rig import RigIO
from hal.schema import build
from hal.transport import counts_to_volts, volts_to_counts
from sim_backend.options import SimOptions
from sim_backend.transport import SimTransport

CATCH_UP_S = 0.02  # the most plant time one request advances by [s]: above a Modbus RTU exchange (~16 ms)


class WiredRig:
    def __init__(self, rig, safe_after_s: float = 0.02):
        options = build(SimOptions, rig.transport.options, "transport.options")
        catch_up = max(min(options.max_catch_up_s, CATCH_UP_S), options.step_s)
        self.sim = SimTransport(rig, dataclasses.replace(options, max_catch_up_s=catch_up), time.monotonic)
        self.sim.open()
        self.n_in, self.n_out = len(self.sim.inputs), len(self.sim.outputs)
        self.safe_volts = RigIO(rig, self.sim).safe_volts
        self.safe_after_s = safe_after_s
        self._last_outputs = time.monotonic()
        self._safe = True

    def apply(self, counts: Sequence[int]) -> None:
        """Drive the DACs with the host's output counts."""
        self.sim.write(counts_to_volts(counts, self.sim.outputs))
        self._last_outputs = time.monotonic()
        self._safe = False

    def sample(self) -> list[int]:
        """Step the plant to the present and return the input counts."""
        return volts_to_counts(self.sim.read().values, self.sim.inputs)

    def watchdog(self) -> None:
        """Write the safe outputs once no outputs have come for ``safe_after_s``, as a real
        node does when its host goes quiet (call it often)."""
        if not self._safe and time.monotonic() - self._last_outputs > self.safe_after_s:
            self.sim.write(self.safe_volts)
            self._safe = True
