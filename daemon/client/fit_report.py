"""The report of a joint model's fit, for ``pneumactl identify`` (its experiments, or any
closed-loop recording): the parameters against the prior with their stated uncertainty, the
held-out Fit [2-49] beside the prior's, and a warning when the new model does not beat it."""
from __future__ import annotations

import sys

import numpy as np

from controllers.identification.simulate import FITTED, samples_per_step

LATE_SHARE = 0.01  # an experiment whose loop lost more than this share of its time to missed deadlines ran late

HELD = {"K_mdl": "not separable from the torque scale", "J": "its pole is far above the band",
        "vs": "below the angle's resolution"}  # at the prior's values (controllers.identification.fit)


def residual_rms(fit: float, data, step: float) -> float:
    """The residual's RMS [deg] on ``data`` (on the fit's grid) that a [2-49] Fit of ``fit`` %
    means: ||y - y_hat|| = (1 - Fit/100) ||y - mean(y)||."""
    m = samples_per_step(step, data.dt)
    return float((1.0 - fit / 100.0) * np.std(data.y[m::m]))


def ran_late(time_base: dict) -> bool:
    """Whether an experiment's loop lost more than LATE_SHARE of its time to missed deadlines
    (its time base, :func:`controllers.identification.data.on_the_period`: the lost share is
    1 - period / mean period)."""
    return 1.0 - time_base["period_s"] / time_base["mean_period_s"] > LATE_SHARE


def against_prior(identified_fit: float, prior_fit: float, time_bases=()) -> str | None:
    """A warning when the identified model does not fit the held-out data better than the
    prior (the rig file's model) does, else None: a new model that explains data it did not
    see no better than the old one is no reason to replace it. When the loop ran late during
    the experiments (``time_bases``, one each), that is said first: a loaded PC's late cycles
    and stale samples are in the data, and longer or larger experiments would not help."""
    if identified_fit > prior_fit:
        return None
    late = [b for b in time_bases if ran_late(b)]
    if late:
        worst = max(late, key=lambda b: b["mean_period_s"])
        advice = (f"the loop ran late during {len(late)} of the {len(time_bases)} experiments (at worst a cycle "
                  f"every {worst['mean_period_s'] * 1e3:.2f} ms for {worst['period_s'] * 1e3:g} ms, "
                  f"{worst['stale_fraction']:.0%} of its samples stale): keep the prior, and run them again with "
                  f"the loop on time ('pneumactl doctor' says what holds it up)")
    else:
        advice = ("keep the prior, or run the full experiments (without --quick) or a larger --amplitude before "
                  "using the new model")
    return (f"warning: the identified model fits the held-out data no better than the prior "
            f"({identified_fit:.1f} % against {prior_fit:.1f} %): {advice}")


def _uncertainty(name: str, value: float) -> str:
    """A fit's uncertainty figure in the terms of its search coordinate."""
    if name in HELD:
        return ""
    return f"{value * 1e3:.1f} ms" if name == "T_dly" else f"{value:.3f} Fs" if name == "Fc" else f"{value * 100:.1f} %"


def print_table(report: dict) -> None:
    """The parameters against the prior, with the uncertainty the fit states (1 sigma: the
    Jacobian's, scaled for the residuals' correlation, the final population's spread, the
    lag/dead-time ridge's and the model's own error, in quadrature) and the population's
    spread alone (how far apart fits the data rates alike are); then the held-out Fit beside
    the prior's, and a warning when the new model does not beat it."""
    print(f"{'parameter':>9} {'prior':>11} {'identified':>11} {'1 sigma':>8} {'spread':>8}  unit", file=sys.stderr)
    for n in FITTED:
        key = n if n != "Fc" else "Fc_ratio"
        figures = [_uncertainty(n, report[kind].get(key, float("nan"))) for kind in ("stated_std", "population_std")]
        print(f"{n:>9} {report['prior'][n]:11.4g} {report['params'][n]:11.4g} {figures[0]:>8} {figures[1]:>8}  "
              f"{report['units'][n]}" + (f"  (held: {HELD[n]})" if n in HELD else ""), file=sys.stderr)
    print(f"Fit [2-49]: {', '.join(f'{v:.1f} %' for v in report['fit_percent'])} fitted, "
          f"{', '.join(f'{v:.1f} %' for v in report['heldout_fit_percent'])} held out "
          f"(the prior: {report['prior_heldout_fit_percent']:.1f} % held out); "
          f"{report['generations']} generations in {report['wall_s']:.1f} s", file=sys.stderr)
    if report["warning"]:
        print(report["warning"], file=sys.stderr)
    print(f"wrote {report['rig_file']} and {', '.join(report['figures'])}", file=sys.stderr)
