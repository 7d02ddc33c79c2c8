"""The simulated rig as an I/O node on a wire sees it: raw counts in and out, on the
real-time clock, and the node's own watchdog. Shared by the peers behind each transport
(serial_peer, modbus_peer, can_peer)."""
from __future__ import annotations

import time
from collections.abc import Sequence

from hal.rig import RigIO
from hal.transport import counts_to_volts, volts_to_counts
from sim_backend.transport import SimTransport


class WiredRig:
    def __init__(self, rig, safe_after_s: float = 0.02):
        self.sim = SimTransport.from_config(rig, time.monotonic)
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
