"""An excitation's signal from its settings: the excite request's signal arguments, checked,
-> the signal the planner runs; and the same signal rebuilt from a recording's settings for
an analysis (:mod:`controllers.identification` is handed :func:`recorded`: controllers never
import the daemon). One function serves both, so the analysis sees the signal that ran."""
from __future__ import annotations

from controllers import signals
from daemon.wire import catalog
from daemon.wire.arguments import bad_args, integer, number, numbers

MAX_INPUT_DURATION_S = 600.0  # an open-loop experiment's signal [s]
NOT_SETTINGS = ("side", "signal", "joint", "amplitude_v", "amplitude_deg")  # a recorded definition's other keys


_EXCITE = catalog.COMMANDS["excite"]


def excite_number(args: dict, key: str, longest: float | None = None) -> float:
    """An excite argument in the catalog's bounds (a duration also within ``longest`` [s]), or
    its default: the same check for a request and for an analysis rebuilding its signal."""
    spec = _EXCITE.arg(key)
    return number(args, key, spec.low, spec.high if longest is None else min(spec.high, longest), spec.default)


def _integer(args: dict, key: str, default: int | None = None) -> int:
    """An integer excite argument in the catalog's bounds (``default``: a signal's own)."""
    spec = _EXCITE.arg(key)
    return integer(args, key, int(spec.low), int(spec.high), spec.default if default is None else default)


def signal_of(args: dict, signal: str, base, j: int, amplitude: float, longest: float) -> signals.Excitation:
    """The signal of the request, about ``base`` on joint j; its duration at most ``longest``.
    The same settings give the same signal: an analysis rebuilds it from the recording."""
    if signal == "chirp":
        f0 = excite_number(args, "f0_hz")
        f1 = excite_number(args, "f1_hz")
        if f1 <= f0:
            raise bad_args(f"'f1_hz' ({f1}) must be above 'f0_hz' ({f0})", "f1_hz")
        return signals.LogChirp(base, j, amplitude, f0, f1, excite_number(args, "duration_s", longest))
    if signal == "prbs":
        made = signals.PRBS(base, j, amplitude, _integer(args, "order"), excite_number(args, "bit_s"),
                            _integer(args, "periods", 1))
    elif signal == "multisine":
        f0 = excite_number(args, "f0_hz")
        f1 = excite_number(args, "f1_hz")
        if f1 <= f0:
            raise bad_args(f"'f1_hz' ({f1}) must be above 'f0_hz' ({f0})", "f1_hz")
        period = excite_number(args, "period_s", min(longest, MAX_INPUT_DURATION_S))
        if f0 * period < 1.0:
            raise bad_args(f"'f0_hz' ({f0}) is below one cycle per period (1 / {period:g} s)", "f0_hz",
                           low=1.0 / period, high=_EXCITE.arg("f0_hz").high)
        made = signals.Multisine(base, j, amplitude, f0, f1, _integer(args, "components"), period,
                                 _integer(args, "periods", 2))
    else:
        raw = args.get("levels")
        if not isinstance(raw, list) or not 1 <= len(raw) <= signals.Levels.MAX_LEVELS:
            raise bad_args(f"'levels' must be a list of 1-{signals.Levels.MAX_LEVELS} numbers (V)", "levels")
        levels = numbers({"levels": raw}, "levels", len(raw))
        if any(abs(v) > 1.0 + 1e-12 for v in levels):
            raise bad_args("'levels' are fractions of amplitude_v, within -1..1", "levels")
        made = signals.Levels(base, j, [amplitude * v for v in levels], excite_number(args, "hold_s"))
    if made.duration > longest:
        raise bad_args(f"the {signal} lasts {made.duration:g} s, over the {longest:g} s allowed", "periods")
    return made


def recorded(definition: dict) -> signals.Excitation:
    """The signal an experiment ran, from its recorded definition (a ``reference`` start
    event's ``signal``), about 0 on joint 0: in volts (``amplitude_v``) for an input-side
    one, of amplitude 1 for a reference-side one."""
    settings = {k: v for k, v in definition.items() if k not in NOT_SETTINGS}
    return signal_of(settings, definition["signal"], [0.0], 0, definition.get("amplitude_v", 1.0),
                     MAX_INPUT_DURATION_S)
