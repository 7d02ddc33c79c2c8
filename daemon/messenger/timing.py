"""The loop's timing judged beside it, in the messenger, from the stats windows it summarises
(:mod:`daemon.wire.loop_stats`): over the rig file's sliding ``[timing] window_s``, the rate
the loop achieved and the deadlines it missed (overruns), and the control stage's median time
in the last window (the controller's step, chiefly), against the rig file's limits
(:class:`hal.rig_sections.TimingConfig`).

Each window's verdict goes to the loop as the catalog's internal command ``timing.verdict``
(as ``lease.revoke`` does), on the control ring: the loop keeps it for ``status``, names the
controller, raises the ``timing`` event when the verdict changes (degraded, or back within the
limits) and applies the rig file's policy at that cycle boundary. Nothing of this costs the
loop more than one small request a window.
"""
from __future__ import annotations

import logging
import math
from collections import deque

import msgpack

from daemon.wire import protocol, routed
from daemon.wire.keys import OPERATOR, Identity
from daemon.wire.ring import Ring
from hal.rig_sections import TimingConfig

JUDGE = Identity("messenger", OPERATOR)  # who the verdict's events name: the messenger judged
ANSWER_LIMIT_S = 60.0  # a verdict the loop has not answered for this long is forgotten [s]
log = logging.getLogger("pneumad")


class TimingJudge:
    def __init__(self, settings: TimingConfig, rings: dict[str, Ring], tokens):
        self.settings, self.ring, self._tokens = settings, rings["control"], tokens
        self._marks: deque[tuple[float, int, int]] = deque()  # (t [s], cycles_total, overruns_total) per window end
        self._asked: dict[int, float] = {}  # a verdict's token -> when it was sent [s, the window's t]

    def take(self, summary: dict) -> dict | None:
        """A stats window's summary (:func:`daemon.wire.loop_stats.summarise`): the verdict over
        the sliding window ending with it, sent to the loop; None until the windows seen span
        ``window_s``."""
        marks, window_s = self._marks, self.settings.window_s
        mark = (summary["t"], summary["cycles_total"], summary["overruns_total"])
        if marks and (mark[0] <= marks[-1][0] or mark[1] < marks[-1][1]):
            marks.clear()  # another loop's counts (never in one daemon's life): start again
        marks.append(mark)
        while len(marks) > 2 and mark[0] - marks[1][0] >= window_s:
            marks.popleft()
        (t0, cycles0, overruns0), (t1, cycles1, overruns1) = marks[0], mark
        if t1 - t0 < window_s:
            return None
        verdict = judge(self.settings, summary["period_us"] * 1e-6, t0, t1, cycles1 - cycles0,
                        overruns1 - overruns0, summary["compute_us"]["control"]["p50"])
        self._tell(verdict)
        return verdict

    def _tell(self, verdict: dict) -> None:
        request = protocol.decode_request(protocol.encode_request("timing", "timing.verdict", verdict))
        token = next(self._tokens)
        if self.ring.put(token, routed.pack(JUDGE, request)):
            self._asked[token] = verdict["t"]
        # a full control ring: the next window's verdict is told instead

    def answer(self, token: int, reply: bytes) -> bool:
        """Take the loop's reply ``token`` if it answers a verdict (a refusal is a bug: said in
        the log); whether it did."""
        if self._asked.pop(token, None) is None:
            return False
        answer = msgpack.unpackb(reply, raw=False)
        if not answer.get("ok"):
            log.error("timing: the loop refused the messenger's verdict: %s", answer.get("error"))
        return True

    def expire(self) -> None:
        """Forget verdicts the loop never answered (a reply it could not queue)."""
        if self._marks:
            latest = self._marks[-1][0]
            self._asked = {t: when for t, when in self._asked.items() if latest - when < ANSWER_LIMIT_S}


def judge(settings: TimingConfig, period: float, t0: float, t1: float, cycles: int, overruns: int,
          control_us: float) -> dict:
    """The verdict on ``cycles`` run and ``overruns`` deadlines missed between ``t0`` and ``t1``
    [s] at ``period`` [s], and the control stage's median time [us]: ``timing.verdict``'s
    arguments (docs/protocol.md). ``reasons``: ``rate``, ``overruns``, ``step``."""
    span = t1 - t0
    expected_hz = 1.0 / period
    rate_hz = cycles / span
    deadlines = cycles + overruns
    overrun_fraction = overruns / deadlines if deadlines else 0.0
    budget_us = settings.step_budget_fraction * period * 1e6
    control = None if control_us is None or math.isnan(control_us) else float(control_us)
    reasons = [reason for reason, crossed in (
        ("rate", rate_hz < settings.min_rate_fraction * expected_hz),
        ("overruns", overrun_fraction > settings.max_overrun_fraction),
        ("step", control is not None and control > budget_us)) if crossed]
    return {"degraded": bool(reasons), "reasons": reasons, "rate_hz": rate_hz, "expected_hz": expected_hz,
            "overruns": overruns, "deadlines": deadlines, "control_us": control, "step_budget_us": budget_us,
            "window_s": span, "since_t": t0, "t": t1}
