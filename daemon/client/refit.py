"""``pneumactl identify JOINT --from RECORDING`` on a recording without identify's experiments:
any closed-loop run the daemon or a client recorded (a path, steps, waypoints; any controller),
fitted from the chamber pressures the loop commanded and the angles it read
(:mod:`controllers.identification.closed_loop`). A run whose excitation does not support a fit
is refused with what it lacks, per joint; a fit states its Fit on the held-out end of the run
and its parameters' uncertainty, as the experiments' fit does (docs/identification.md "From
any recording"). Runs in the client's process, never in the daemon's."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from controllers.identification import closed_loop, plots, rigfile
from controllers.identification import data as experiments_of
from controllers.identification.fit import C_SPAN, best_c, fit_joint
from controllers.identification.simulate import FITTED
from daemon.client.fit_report import against_prior, print_table
from hal.identified import UNITS


def refit(run, path: Path, joint: str, out: Path, population: int, generations: int, seed: int = 0) -> dict:
    """Fit ``joint``'s model to the closed-loop run in recording ``run`` (read from ``path``):
    the first part fitted, the rest held out; the figure, the rig file and the report into
    ``out``; the report. SystemExit saying what the run lacks when it does not support a fit."""
    rig = experiments_of.rig_of(run)
    prior = experiments_of.prior_of(rig, joint)
    whole = closed_loop.run_experiment(run, str(path), joint)
    fitted = closed_loop.split(whole)
    lacking = closed_loop.excitation(fitted, prior)
    if lacking:
        raise SystemExit(f"{path}: its run does not support a fit of joint {joint}'s model:\n  "
                         + "\n  ".join(lacking)
                         + f"\nrecord a path, steps or waypoints that move joint {joint} (the motion commands' "
                           f"--record), or run `pneumactl identify {joint}`'s experiments")
    started = ("at rest" if whole.info["from_rest"] else
               "at its slowest moment (no rest in the run: its start is approximate)")
    print(f"{path.name}: no identification experiment on {joint}: fitting its closed-loop run, "
          f"{whole.t[-1]:.1f} s from {started}, the first {closed_loop.ESTIMATION_FRACTION:.0%} fitted",
          file=sys.stderr, flush=True)
    result = fit_joint([fitted], prior, [], population=population, generations=generations, seed=seed)
    step = result.settings["step_s"]
    held, rms, identified_y = closed_loop.tail_fit(result.params, whole, fitted, step, result.c[0])
    prior_c = best_c(prior, fitted, step, C_SPAN * prior.Fs)  # the prior's start chosen on the fitted part too
    prior_fit, _, prior_y = closed_loop.tail_fit(prior, whole, fitted, step, prior_c)
    verdict = against_prior(held, prior_fit)
    ratio, weakest, unsettled = closed_loop.information(fitted, prior, step)
    out.mkdir(parents=True, exist_ok=True)
    figure = plots.run_overlay(out / f"run-{joint}.png", joint, whole, float(fitted.t[-1]),
                               [("identified", identified_y, held), ("prior", prior_y, prior_fit)], step)
    judged = {"heldout_fit_percent": held, "heldout_rms_deg": rms}
    name = f"{joint}-identified"
    provenance = (f"pneumactl identify {time.strftime('%Y-%m-%d %H:%M:%S')}: {path.name} "
                  f"(rig {run.describe['rig']['hash'][:12]}), its closed-loop run ({whole.t[-1]:.1f} s), fitted "
                  f"on its first {closed_loop.ESTIMATION_FRACTION:.0%}, held-out Fit {held:.1f} % on the rest "
                  f"(the prior's {prior_fit:.1f} %{'' if verdict is None else ': NOT BETTER'})")
    rig_path = out / "rig.toml"
    rig_path.write_text(rigfile.with_model(rig.source, joint, name, result.params, provenance, judged))
    summary = result.summary()
    report = {"joint": joint, "model": name, "rig_file": str(rig_path), "recording": str(path),
              "figures": [str(figure)], **summary, "heldout_fit_percent": [held], "judged": judged,
              "prior_heldout_fit_percent": prior_fit, "beats_prior": verdict is None, "warning": verdict,
              "prior": {n: getattr(prior, n) for n in FITTED}, "units": {n: UNITS[n] for n in FITTED},
              "experiments": [whole.info["signal"]], "closed_loop": {
                  "run_s": float(whole.t[-1]), "from_rest": whole.info["from_rest"],
                  "start_cycle": whole.info["start_cycle"], "fitted_fraction": closed_loop.ESTIMATION_FRACTION,
                  "saturated_fraction": whole.info["saturated_fraction"],
                  "information_ratio": ratio, "weakest": weakest, "unsettled": unsettled}}
    (out / "report.json").write_text(json.dumps(report, indent=2))
    print_table(report)
    print(f"the run tells {weakest} apart least (the information matrix's smallest eigenvalue {ratio:.1e} of "
          f"its largest)" + (f"; it leaves {', '.join(unsettled)} unsettled: traded against each other, beyond the "
                             f"uncertainty stated for them (a run that moves the joint faster and more ways, or "
                             f"`pneumactl identify`'s experiments, pins them)" if unsettled else ""),
          file=sys.stderr, flush=True)
    return report
