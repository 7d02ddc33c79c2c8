"""The loop's side of its timing verdicts: the messenger judges the loop's rate, overruns and
control-stage time beside it (:mod:`daemon.messenger.timing`) and sends its verdict each stats
window as the internal command ``timing.verdict``; here, at a cycle boundary, it is kept for
``status`` (the field ``timing``), the active controller is named when its step is over budget,
a ``timing`` event is raised when the verdict changes (degraded, back within the limits, or
while degraded other reasons or another controller named: each with the window's figures),
and the rig file's ``[timing] policy`` is applied while it is degraded: ``warn`` nothing more,
``hold`` a controller over its step budget replaced by the rig file's fallback controller (or
``hold``), a running reference stopped and the arm held where it is (motion commands refused
meanwhile), ``trip`` an enabled arm tripped (and ``enable`` refused meanwhile). Constant work, once a window.
"""
from __future__ import annotations

from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed


class TimingVerdicts:
    def __init__(self, controls, view, events):
        """``controls``: the loop's named controls (``hold``, ``trip``); ``view``: its view;
        ``events``: its event log."""
        self.controls, self.view, self.events = controls, view, events
        self.settings = view.rig.timing
        self.status = {"degraded": False, "since": None, "cause": "", "reasons": [], "rate_hz": None,
                       "expected_hz": None, "overruns": None, "deadlines": None, "control_us": None,
                       "step_budget_us": None, "controller": None, "window_s": self.settings.window_s,
                       "judged_t": None, "policy": self.settings.policy, "fallback": None}

    def take(self, verdict: dict) -> dict:
        """A verdict (``timing.verdict``'s arguments): kept, told when it changes (degraded, back
        within the limits, or while degraded other reasons or another controller named), acted on
        with its own figures."""
        status, degraded = self.status, bool(verdict["degraded"])
        flipped = degraded != status["degraded"]
        over_budget = "step" in verdict.get("reasons", ())
        controller = self.view.controller.name if over_budget else None
        changed = flipped or degraded and (list(verdict.get("reasons", ())) != status["reasons"]
                                           or controller != status["controller"])
        status.update({key: verdict.get(key) for key in ("rate_hz", "expected_hz", "overruns", "deadlines",
                                                          "control_us", "step_budget_us", "window_s")})
        status.update(degraded=degraded, reasons=list(verdict.get("reasons", ())), controller=controller,
                      judged_t=verdict.get("t"))
        if flipped:
            status["since"] = verdict.get("t")
            status["fallback"] = None
        if changed or degraded:  # the figures of this window: what status, the event and a trip say
            status["cause"] = self._cause(verdict, status)
        action = self._act(status["cause"]) if degraded else "none"
        if changed:
            self.events.add({"kind": "timing", "degraded": degraded, "cause": status["cause"], "action": action,
                             "policy": self.settings.policy, "window_s": verdict.get("window_s"),
                             "since_t": verdict.get("since_t"),
                             **{key: status[key] for key in ("reasons", "rate_hz", "expected_hz", "overruns",
                                                             "deadlines", "control_us", "step_budget_us",
                                                             "controller", "fallback")}})
        return {"degraded": degraded, "action": action}

    def _act(self, cause: str) -> str:
        """The policy, while degraded: what it did now (``none``: nothing to do)."""
        policy = self.settings.policy
        if policy == "trip" and self.view.enabled:
            self.controls.trip(f"timing degraded: {cause}")
            return "trip"
        if policy == "hold" and self.view.enabled:
            slow = self.status["controller"]
            if slow is not None and slow == self.view.controller.name:  # still the active one: replaced
                took, budget = self.status["control_us"] or 0.0, self.status["step_budget_us"] or 0.0
                self.status["fallback"] = self.controls.fall_back(f"its step took {took:.0f} us (median), over its "
                                                                  f"budget of {budget:.0f} us")
                return "fallback"
            if self.view.reference_running()[1] > 0.0:
                self.controls.hold()
                return "hold"
        return "warn" if policy == "warn" else "none"

    def check_motion(self) -> None:
        """Refuse a motion command (``bad_state``, reason ``timing``) while degraded under ``hold``."""
        if self.status["degraded"] and self.settings.policy == "hold":
            raise CommandFailed(P.BAD_STATE, f"the loop's timing is degraded ({self.status['cause']}); the rig file's "
                                             f"[timing] policy = \"hold\" holds the arm until it is back within its "
                                             f"limits", {"reason": "timing"})

    def check_enable(self) -> None:
        """Refuse ``enable`` (``bad_state``, reason ``timing``) while degraded under ``trip``: the
        policy would trip the arm at the next verdict."""
        if self.status["degraded"] and self.settings.policy == "trip":
            raise CommandFailed(P.BAD_STATE, f"the loop's timing is degraded ({self.status['cause']}); the rig file's "
                                             f"[timing] policy = \"trip\" would trip the arm at the next verdict: "
                                             f"enable once it is back within its limits", {"reason": "timing"})

    def _cause(self, verdict: dict, status: dict) -> str:
        """The verdict in words: the figures, each against its limit."""
        s = self.settings
        rate, expected, deadlines = verdict.get("rate_hz") or 0.0, verdict.get("expected_hz") or 1.0, \
            verdict.get("deadlines") or 0
        overruns = verdict.get("overruns") or 0
        missed = overruns / deadlines if deadlines else 0.0
        rate_limit = f", limit {s.min_rate_fraction:.0%}" if s.min_rate_fraction > 0.0 else ""
        missed_limit = f", limit {s.max_overrun_fraction:.1%}" if s.max_overrun_fraction < 1.0 else ""
        text = (f"the loop ran at {rate:.0f} Hz of {expected:.0f} Hz ({rate / expected:.0%}{rate_limit}) over the "
                f"last {verdict.get('window_s', 0.0):.1f} s, missing {overruns} of {deadlines} deadlines "
                f"({missed:.1%}{missed_limit})")
        control = verdict.get("control_us")
        if control is not None:
            who = f"controller {status['controller']}'s step" if status["controller"] else "the control stage"
            text += f"; {who} took {control:.0f} us (median, budget {verdict.get('step_budget_us', 0.0):.0f} us)"
        if status["degraded"]:
            return f"{text}: runs meanwhile are not valid at the loop's rate (rig file [timing], policy {s.policy})"
        return f"{text}: back within the rig file's [timing] limits"
