"""A reference's samples, cycle by cycle from a run's start, kept across the cases that run it
from the same time (the controllers compared on one plant and path): sampled once, by the
trajectory's own Python ``sample``, at the run's own cycle times (the same sums of the period
the loop makes)."""
from __future__ import annotations

import numpy as np

_KEPT: dict = {}  # (reference key, t0) -> its Samples


class Samples:
    """The samples so far (``rows``: (angles, velocities, accelerations) each), their angles as
    an array (``angles``, a row a cycle) and the time of the next cycle to sample."""

    def __init__(self):
        self.rows: list = []
        self.angles = np.zeros((0, 0))
        self.next_t: float | None = None

    def extend(self, count: int, trajectory, t0: float, t_first: float, period: float) -> None:
        """Samples for the run's first ``count`` cycles, its first at ``t_first``."""
        rows = self.rows
        if len(rows) < count:
            t = self.next_t if rows else t_first
            while len(rows) < count:
                rows.append(trajectory.sample(t - t0))
                t += period
            self.next_t = t
        if len(self.angles) < count:
            fresh = np.array([r[0] for r in rows[len(self.angles):]], dtype=float)
            self.angles = fresh if not len(self.angles) else np.concatenate([self.angles, fresh])

    def sampled(self, row, t_next: float) -> None:
        """One more sample, taken by the Python engine; the next cycle is at ``t_next``."""
        self.rows.append(row)
        self.next_t = t_next


def kept(key, t0: float) -> Samples:
    """The samples kept of the reference ``key`` run from ``t0`` (a case's approach and its path:
    the last four, for the controllers compared on them, which the pool spreads over its workers)."""
    if (key, t0) not in _KEPT:
        while len(_KEPT) >= 4:
            del _KEPT[next(iter(_KEPT))]
        _KEPT[(key, t0)] = Samples()
    return _KEPT[(key, t0)]
