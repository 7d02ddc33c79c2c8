"""An excitation's signal from its settings: the excite request's signal arguments, checked,
-> the signal the planner runs; and the same signal rebuilt from a recording's settings for
an analysis (:mod:`controllers.identification` is handed :func:`recorded`: controllers never
import the daemon). One function serves both, so the analysis sees the signal that ran."""
from __future__ import annotations

from controllers import signals
from daemon.wire.arguments import bad_args, integer, number, numbers

MAX_INPUT_DURATION_S = 600.0  # an open-loop experiment's signal [s]
NOT_SETTINGS = ("side", "signal", "joint", "amplitude_v", "amplitude_deg")  # a recorded definition's other keys


def signal_of(args: dict, signal: str, base, j: int, amplitude: float, longest: float) -> signals.Excitation:
    """The signal of the request, about ``base`` on joint j; its duration at most ``longest``.
    The same settings give the same signal: an analysis rebuilds it from the recording."""
    if signal == "chirp":
        f0 = number(args, "f0_hz", 0.001, 100.0, 0.1)
        f1 = number(args, "f1_hz", 0.001, 100.0, 1.0)
        if f1 <= f0:
            raise bad_args(f"'f1_hz' ({f1}) must be above 'f0_hz' ({f0})", "f1_hz")
        return signals.LogChirp(base, j, amplitude, f0, f1, number(args, "duration_s", 1.0, longest, 60.0))
    if signal == "prbs":
        made = signals.PRBS(base, j, amplitude, integer(args, "order", 2, 16, 8), number(args, "bit_s", 0.001, 60.0, 0.2),
                            integer(args, "periods", 1, 100, 1))
    elif signal == "multisine":
        f0 = number(args, "f0_hz", 0.001, 100.0, 0.1)
        f1 = number(args, "f1_hz", 0.001, 100.0, 1.0)
        if f1 <= f0:
            raise bad_args(f"'f1_hz' ({f1}) must be above 'f0_hz' ({f0})", "f1_hz")
        period = number(args, "period_s", 1.0, min(longest, MAX_INPUT_DURATION_S), 20.0)
        if f0 * period < 1.0:
            raise bad_args(f"'f0_hz' ({f0}) is below one cycle per period (1 / {period:g} s)", "f0_hz")
        made = signals.Multisine(base, j, amplitude, f0, f1,
                                 integer(args, "components", 1, signals.Multisine.MAX_COMPONENTS, 16), period,
                                 integer(args, "periods", 1, 100, 2))
    else:
        raw = args.get("levels")
        if not isinstance(raw, list) or not 1 <= len(raw) <= signals.Levels.MAX_LEVELS:
            raise bad_args(f"'levels' must be a list of 1-{signals.Levels.MAX_LEVELS} numbers (V)", "levels")
        levels = numbers({"levels": raw}, "levels", len(raw))
        if any(abs(v) > 1.0 + 1e-12 for v in levels):
            raise bad_args("'levels' are fractions of amplitude_v, within -1..1", "levels")
        made = signals.Levels(base, j, [amplitude * v for v in levels], number(args, "hold_s", 0.01, 60.0, 2.0))
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
