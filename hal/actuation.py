"""The actuation scheme of rig-facts §1 [2-30..2-35]: one manipulated variable per joint.

The head chamber is commanded ``V_H = V_INI,H + V_MV``, the rod chamber held at ``V_L = V_INI,L``;
the regulator line [2-29] turns those volts into chamber pressure commands [Pa]. The
constant force due to the biases is an offset the controller's integral absorbs.
"""
from __future__ import annotations

from collections.abc import Sequence

from hal.regulator import ITV0051, V_MAX, V_MIN


class BiasedHeadActuation:
    """V_MV per joint [V] -> (head, rod) chamber pressure commands [Pa]."""

    def __init__(self, head: Sequence[ITV0051], rod: Sequence[ITV0051]):
        self._head = list(head)
        self._bias_v = [r.config.bias_volts for r in head]
        self._rod_pa = tuple(r.bias_pa for r in rod)
        self.u_min = tuple(V_MIN - b for b in self._bias_v)  # V_MV range that stays within 0-10 V
        self.u_max = tuple(V_MAX - b for b in self._bias_v)

    def pressures(self, v_mv: Sequence[float]) -> tuple[list[float], tuple[float, ...]]:
        head = [reg.pressure(b + u) for reg, b, u in zip(self._head, self._bias_v, v_mv)]
        return head, self._rod_pa
