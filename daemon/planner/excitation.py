"""Planning identification experiments (``excite``), beside the loop (rig-facts §1 "Experiments").

``side: "reference"`` (the default) adds the signal to one joint's reference about its
set-point (``amplitude_deg`` on a rotary joint, ``amplitude_mm`` on a linear one): a
closed-loop experiment. ``side: "input"`` holds every joint at its
set-point and, after ``settle_s``, adds the signal to the excited joint's V_MV [V] with its
feedback set aside (:mod:`controllers.experiment`): an open-loop one. The input side is
checked before it runs: the band (``band_deg`` about the set-point; a linear joint's
``band_mm``) inside the joint's limits,
the operating point's V_MV (from the nominal model) plus the signal's peak inside the V_MV
range, and the nominal linear model's predicted excursion (friction and the centring aside,
so an overestimate) inside the band; the centring PI's gains come from the nominal model
(``centre_hz`` its crossover, 0 for none); the loop stops it (holding the joint where it
is) if the joint leaves the band all the same. The cost of these checks grows with the signal's duration, so they run
here, never in the loop.
"""
from __future__ import annotations

import math

import numpy as np

from controllers.experiment import InputExperiment
from daemon.wire.catalog import MAX_DURATION_S, SIGNAL_SETTINGS
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed, bad_args, choice
from daemon.wire.signals import MAX_INPUT_DURATION_S, excite_number as _number, signal_of
from daemon.planner.plans import Plan, PlanContext, check_authority

PREDICTION_STEP_S = 0.005  # the excursion prediction's grid [s]


def plan_excite(ctx: PlanContext, args: dict, setpoint: list[float]) -> Plan:
    args = dict(args)
    # names, types, bounds, and which arguments a side and a signal take: checked against the catalog by the messenger
    side = args.pop("side", "reference")
    signal = args["signal"]
    joint = choice(args, "joint", ctx.joint_names)
    j = ctx.joint_names.index(joint)
    if side == "input":
        return _plan_input(ctx, args, setpoint, signal, joint, j)
    unit, scale = ctx.display(j)
    key = f"amplitude_{unit}"
    other = "amplitude_mm" if unit == "deg" else "amplitude_deg"
    if other in args or key not in args:
        raise bad_args(f"joint {joint} is {'rotary' if unit == 'deg' else 'linear'}: give the reference side's "
                       f"amplitude as {key}", other if other in args else key)
    amplitude = _number(args, key) / scale
    excitation = signal_of(args, signal, setpoint, j, amplitude, MAX_DURATION_S)
    _check_band(ctx, j, setpoint[j], excitation.peak, key, ctx.margins[j] if ctx.margins else 0.0)
    check_authority(ctx, f"the {signal}", excitation,
                    "lower the amplitude" + (" or the top frequency" if signal != "prbs" else ""))
    excitation.definition = {"side": "reference", "signal": signal, "joint": joint,
                             key: amplitude * scale, **_settings(args, signal)}
    return Plan(excitation, signal, {"signal": signal, "joint": joint, "side": "reference",
                                     "duration_s": excitation.duration}, tuple(setpoint))


def _check_band(ctx: PlanContext, j: int, centre: float, half: float, argument: str, margin: float = 0.0) -> None:
    """A limits refusal in the joint's unit unless centre +- half [SI] is inside its limits by
    ``margin`` [SI]: a reference excitation keeps the set-points' margin (a controller's overshoot
    past a reference at a limit would trip the arm, as past a set-point there)."""
    lo, hi = ctx.limits[j]
    if lo + margin <= centre - half and centre + half <= hi - margin:
        return
    unit, scale = ctx.display(j)
    what = "angle" if unit == "deg" else "position"
    if lo <= centre - half and centre + half <= hi:
        words, shown = ctx.margin_words(j, margin, "references")
        raise CommandFailed(P.REFUSED, f"joint {ctx.joint_names[j]} at {ctx.text(j, centre, 1)} +- "
                                       f"{ctx.text(j, half, 1)} ({argument}) comes within {words}",
                            {"reason": "limits", "argument": argument, "joint": ctx.joint_names[j],
                             f"{what}_{unit}": _outermost(centre, half, lo, hi) * scale,
                             f"limits_{unit}": [lo * scale, hi * scale], f"margin_{unit}": shown})
    raise CommandFailed(P.REFUSED, f"joint {ctx.joint_names[j]} at {ctx.text(j, centre, 1)} +- "
                                   f"{ctx.text(j, half, 1)} ({argument}) leaves its limits "
                                   f"{lo * scale:.1f}..{hi * scale:.1f} {unit}",
                        {"reason": "limits", "argument": argument, "joint": ctx.joint_names[j],
                         f"{what}_{unit}": _outermost(centre, half, lo, hi) * scale,
                         f"limits_{unit}": [lo * scale, hi * scale]})


def _outermost(centre: float, half: float, lo: float, hi: float) -> float:
    """The end of centre +- half that leaves lo..hi the most [rad]: a limits refusal's angle."""
    return centre - half if lo - (centre - half) >= (centre + half) - hi else centre + half


def _settings(args: dict, signal: str) -> dict:
    return {k: args[k] for k in SIGNAL_SETTINGS[signal] if k in args}


def _plan_input(ctx: PlanContext, args: dict, setpoint: list[float], signal: str, joint: str, j: int) -> Plan:
    volts = _number(args, "amplitude_v")
    settle = _number(args, "settle_s")
    unit, scale = ctx.display(j)
    band_key = f"band_{unit}"
    other = "band_mm" if unit == "deg" else "band_deg"
    if other in args:
        raise bad_args(f"joint {joint} is {'rotary' if unit == 'deg' else 'linear'}: its band is {band_key}", other)
    band = _number(args, band_key) / scale
    centre_hz = _number(args, "centre_hz")
    excitation = signal_of(args, signal, [0.0], 0, volts, MAX_INPUT_DURATION_S)
    q = setpoint[j]
    _check_band(ctx, j, q, band, band_key)
    t = np.arange(0.0, excitation.duration, PREDICTION_STEP_S)
    u = excitation.series(t)
    peak = float(np.max(np.abs(u))) if len(u) else 0.0
    model = ctx.authority.models[j] if ctx.authority is not None else None
    u_op = model.static_volts(q, 0.0, 0.0) if model is not None else None
    load = ctx.authority.load if ctx.authority is not None else None
    if u_op is not None and load is not None:  # a known payload's holding volts are in the operating point
        u_op += load.volts(setpoint)[j]
    if ctx.authority is not None:
        u_lo, u_hi = ctx.authority.u_min[j], ctx.authority.u_max[j]
        centre = u_op if u_op is not None else 0.0
        if centre - peak < u_lo or centre + peak > u_hi:
            raise CommandFailed(P.REFUSED, f"joint {joint} needs about {centre:+.2f} V of V_MV to hold "
                                           f"{ctx.text(j, q, 1)}; +- {peak:.2f} V of signal leaves the command range "
                                           f"{u_lo:+.2f}..{u_hi:+.2f} V: lower amplitude_v",
                                {"reason": "input_range", "argument": "amplitude_v", "joint": joint,
                                 "u_op_v": centre, "peak_v": peak, "range_v": [u_lo, u_hi]})
    excursion = None
    if model is not None:
        excursion = predicted_excursion(model, u)
        if excursion > band:
            raise CommandFailed(P.REFUSED, f"the {signal} is predicted to move joint {joint} "
                                           f"{math.degrees(excursion):.1f} deg from its operating point, beyond "
                                           f"band_deg {math.degrees(band):.1f}: lower amplitude_v (or raise the "
                                           f"signal's lowest frequency)",
                                {"reason": "excursion", "argument": "amplitude_v", "joint": joint,
                                 "predicted_deg": math.degrees(excursion), "band_deg": math.degrees(band)})
    gains = centring_gains(model, centre_hz) if model is not None else (0.0, 0.0)
    definition = {"side": "input", "signal": signal, "joint": joint, "amplitude_v": volts, "settle_s": settle,
                  band_key: band * scale, f"operating_point_{unit}": ctx.shown(setpoint),
                  f"centre_v_per_{unit}": gains[0] / scale, **_settings(args, signal)}
    experiment = InputExperiment(setpoint, j, excitation, settle, (q - band, q + band), definition, gains)
    reply = {"signal": signal, "joint": joint, "side": "input", "duration_s": experiment.duration, "settle_s": settle,
             "predicted_excursion_deg": None if excursion is None else math.degrees(excursion),
             "u_op_estimate_v": u_op}
    return Plan(experiment, f"{signal}-input", reply, tuple(setpoint))


def centring_gains(model, crossover_hz: float) -> tuple[float, float]:
    """(kp [V/rad], ki [V/(rad s)]) of a PI that crosses over at ``crossover_hz`` on the joint's
    slow dynamics kt / (D s + K) [rad/V] (the viscous term dominates there): |kp kt / (D j w)| = 1,
    its zero a third of the crossover below."""
    w = 2 * math.pi * crossover_hz
    kp = w * model.D / model.kt
    return kp, kp * w / 3.0


def predicted_excursion(model, u: np.ndarray) -> float:
    """The largest |angle change| [rad] the nominal linear model [2-50] (friction and dead time
    aside) predicts for V_MV changes u [V] on PREDICTION_STEP_S, from rest."""
    from scipy.signal import cont2discrete, lfilter  # here, off the loop: at module level it cost
    # the loop's process 1-2 s of every daemon start
    den = np.polymul([model.J, model.D, model.K], [model.T_ep, 1.0])
    num_d, den_d, _ = cont2discrete(([model.kt], den), PREDICTION_STEP_S, method="zoh")
    y = lfilter(np.ravel(num_d), den_d, u)
    return float(np.max(np.abs(y))) if len(y) else 0.0
