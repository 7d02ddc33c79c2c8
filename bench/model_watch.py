"""The model beside the arm on the simulated rig (docs/model.md): nominal runs with noise, to see
that no flag is raised, and each drift the tests inject, to see how soon it is flagged.

Usage: python -m bench.model_watch [--runs 12] [--seconds 300] [--drifts] [--figures DIR]

``--runs`` nominal runs of ``--seconds`` each (the built-in rig, each with its own noise seed:
``adc_noise_volts`` 0.5 mV on every input), the arm swinging through waypoints 2 s apart, the
real loop on the virtual clock (daemon.testing.drift), the model fed its state messages as the
model process is. Per run: each joint's largest window RMS and the flags raised. ``--drifts``:
each drift from 8 s on, 32 s, the time to its flag and the cause named. ``--figures``: the PNGs
docs/model.md shows (the nominal window RMS over all runs against the band; each drift's
residual, its onset and its flag).
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from bench.common import header
from daemon.testing.drift import DRIFTS, drifted_rig, swing, watch
from hal import config

ONSET_S = 8.0


def nominal_run(seed: int, seconds: float) -> dict:
    """One nominal run with noise seed ``seed``: each joint's window RMS over the run, flags raised."""
    text = config.load().source.replace("seed = 1\n", f"seed = {seed}\n", 1)
    rig = config.parse(text)
    from controllers.drift_watch import ModelWatch
    model = ModelWatch(rig)
    period = 1.0 / rig.model_watch.publish_hz
    rms: dict[str, list[float]] = {name: [] for name in model.joints}
    flags: list[str] = []
    due = [-1.0]

    def feed(m: dict) -> None:
        model.feed(m)
        if model.t >= due[0]:
            due[0] = model.t + period
            message, verdicts = model.judge()
            for name, j in message["joints"].items():
                if j["window_fill"] == 1.0:
                    rms[name].append(j["rms_deg"])
            flags.extend(f"{v.joint} {v.action} at {model.t:.1f} s: {v.cause}" for v in verdicts)

    swing(text, seconds, feed=feed)
    return {"seed": seed, "rms": rms, "flags": flags, "band_deg": rig.model_watch.band_deg}


def drift_run(name: str) -> dict:
    text = drifted_rig(DRIFTS[name], at_s=ONSET_S)
    watched = watch(text, swing(text, ONSET_S + 24.0))
    bottom = [(t, v) for t, v in watched.verdicts if v.joint == "bottom"]
    flagged = next((t for t, v in bottom if v.action == "drift"), math.nan)
    named = [(t, v.action, v.details.get("likely"), v.details.get("best"), v.details.get("explained"),
              v.details.get("size")) for t, v in bottom if v.action in ("drift", "cause")]
    return {"name": name, "flagged_after_s": flagged - ONSET_S, "named": named, "t": np.asarray(watched.times),
            "residual": np.asarray(watched.residuals["bottom"]), "flagged_t": flagged,
            "others": [v.joint for _, v in watched.verdicts if v.joint != "bottom"]}


def figures(out: Path, nominal: list[dict], drifts: list[dict]) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    written = []
    if nominal:
        fig, ax = plt.subplots(figsize=(8, 4))
        band = nominal[0]["band_deg"]
        for name in nominal[0]["rms"]:
            values = np.concatenate([r["rms"][name] for r in nominal])
            ax.hist(values, bins=80, histtype="step", lw=1.2, label=f"{name}: largest {values.max():.3f} deg")
        ax.axvline(band, color="C3", ls="--", label=f"band {band:g} deg")
        ax.set_xlabel("residual RMS over a 2 s window [deg]")
        ax.set_ylabel("windows (10 a second)")
        total = sum(len(r["rms"][next(iter(r["rms"]))]) for r in nominal) / 10.0
        ax.set_title(f"nominal runs with noise: {len(nominal)} runs, {total / 60:.1f} min judged, "
                     f"{sum(len(r['flags']) for r in nominal)} flags")
        ax.set_xlim(0, band * 1.1)
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = out / "model-nominal.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        written.append(path)
    if drifts:
        fig, axes = plt.subplots(len(drifts), 1, figsize=(9, 2.4 * len(drifts)), sharex=True)
        for ax, d in zip(np.atleast_1d(axes), drifts):
            ax.plot(d["t"], d["residual"], lw=0.8)
            ax.axvline(ONSET_S, color="0.4", ls=":", label="drift starts")
            if math.isfinite(d["flagged_t"]):
                ax.axvline(d["flagged_t"], color="C3", ls="--", label=f"flagged after {d['flagged_after_s']:.1f} s")
            last = d["named"][-1] if d["named"] else None
            said = (last[2] or f"unclear (best {last[3]})") if last else "none"
            ax.set_title(f"{DRIFTS[d['name']].splitlines()[0]}: named {said} 10 s after its flag", fontsize=9)
            ax.set_ylabel("residual [deg]")
            ax.legend(fontsize=7, loc="upper left")
        np.atleast_1d(axes)[-1].set_xlabel("time [s] (the bottom joint; the arm swings through waypoints 2 s apart)")
        fig.tight_layout()
        path = out / "model-drifts.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        written.append(path)
    return written


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=12)
    p.add_argument("--seconds", type=float, default=300.0)
    p.add_argument("--drifts", action="store_true")
    p.add_argument("--figures", default=None)
    args = p.parse_args(argv)
    header("the model beside the arm on the simulated rig (docs/model.md)")
    nominal = []
    for seed in range(1, args.runs + 1):
        started = time.monotonic()
        run = nominal_run(seed, args.seconds)
        nominal.append(run)
        worst = {n: max(v) if v else math.nan for n, v in run["rms"].items()}
        print(f"nominal seed {seed}: {args.seconds:g} s, largest window RMS "
              f"{', '.join(f'{n} {w:.3f} deg' for n, w in worst.items())} (band {run['band_deg']:g}), "
              f"{len(run['flags'])} flags{': ' + '; '.join(run['flags']) if run['flags'] else ''} "
              f"[{time.monotonic() - started:.0f} s wall]", flush=True)
    drifts = []
    if args.drifts:
        for name in DRIFTS:
            d = drift_run(name)
            drifts.append(d)
            named = "; ".join(f"{a} at {t:.1f} s: {lk or 'unclear'} (best {b}, R2 {e:.3f}, size {s:.3g})"
                              for t, a, lk, b, e, s in d["named"])
            others = f"; other joints flagged: {d['others']}" if d["others"] else ""
            print(f"drift {name}: flagged {d['flagged_after_s']:.1f} s after it started; named {named}{others}",
                  flush=True)
    if args.figures:
        for path in figures(Path(args.figures), nominal, drifts):
            print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
