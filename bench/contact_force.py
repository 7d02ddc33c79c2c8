"""The array sensor's contact estimators on simulated impacts (rig-facts §3): accuracy against
the simulator's truth, the daemon's estimator against the paper's S-WLS + RLS (as read) and
plain WLS on the same frames, and what a frame costs against the sensor's 4 kHz.

    python -m bench.contact_force [--impacts 5] [--seed 0] [--plot PNG] [--bound] [--off-nominal]

For each of the paper's contact speeds (0.03, 0.08, 0.11 m/s), ``--impacts`` impacts with
their own centre, slide, aspect, final beta, pad (gain and offset spread, two dead taxels) and
noise; errors are taken on every frame where the true contact is at least two taxels (5 mm)
in its semi-axis b (a smaller one is not resolved by a 2.5 mm pitch). The tables give the
largest error over all of them, the RMS and the 99.9th percentile, then the largest once b is
2.5 taxels or more; the centre's miss is relative to b. The daemon's estimator also reports
each parameter's 1 sigma: z = error / sigma over the same frames (RMS near 1 when the sigma
tells the truth). ``--bound``: the information in the frames themselves, at each impact's
first counted frame, as the 1 sigma of beta that no estimator following a straight-line
course of the parameters could beat (every frame since first touch, the true contact, the
sensor's noise). ``--off-nominal``: impacts of shapes the estimator was not tuned on. Frame
cost: the daemon's estimator alone, one process, per frame (mean, 99th percentile, largest).
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np

from bench.common import header
from controllers.contact_force import NOISE_PA, ContactEstimator, levels_model, to_levels
from controllers.contact_model import MM, SensingGrid, contact_region, dilate
from controllers.contact_paper import PaperSWLS, PlainWLS
from hal.taxel_array import PAD_M, TAXELS, TaxelArray
from sim_backend.contact_patch import Impact, SimTaxelPad, spread_calibration

FRAME_HZ = 4000.0
SPEEDS = (0.03, 0.08, 0.11)
COLUMNS = ("a", "b", "p_max", "beta", "force_n", "centre")
SIGMAS = ("a_sd", "b_sd", "p_max_sd", "beta_sd", "force_sd_n")
COUNTED_B_M = 2 * PAD_M / TAXELS
LARGER_TAXELS = 2.5  # semi-axis b in taxels from which the second table counts
OURS = "tracker (daemon's)"
ESTIMATORS = {OURS: ContactEstimator, "S-WLS + RLS (paper)": PaperSWLS, "plain WLS": PlainWLS}
OFF_NOMINAL = {  # name: (the impact's changes, the pad's noise scale)
    "short impact, 0.2 s": ({"duration_s": 0.2}, 1.0),
    "long impact, 1 s": ({"duration_s": 1.0}, 1.0),
    "fast load (peak at 20 %)": ({"loading_fraction": 0.2}, 1.0),
    "slow load (peak at 80 %)": ({"loading_fraction": 0.8}, 1.0),
    "aspect 0.6 -> 1.0": ({"aspect": 0.6, "aspect_end": 1.0}, 1.0),
    "beta 0.5 -> 0.3 (flattening)": ({"beta_peak": 0.3}, 1.0),
    "beta 0.5 -> 1.5": ({"beta_peak": 1.5}, 1.0),
    "noise twice the sensor's": ({}, 2.0),
}


def impacts(speed: float, count: int, seed: int):
    """``count`` impacts at ``speed`` with their own centre, slide, pad and noise."""
    rng = np.random.default_rng(seed)
    for i in range(count):
        centre = tuple(rng.uniform(-0.004, 0.004, 2))
        slide = tuple(rng.uniform(-0.008, 0.008, 2))
        dead = tuple((int(r), int(c)) for r, c in rng.integers(4, 12, (2, 2)))
        yield Impact(speed, centre_m=centre, slide_m_s=slide, aspect=float(rng.uniform(0.7, 1.0)),
                     beta_peak=float(rng.uniform(0.6, 1.0))), spread_calibration(int(rng.integers(1 << 30)), dead), i


def run(impact: Impact, calibration, seed: int, noise_scale: float = 1.0, trace: list | None = None):
    """Per estimator, one row per frame that counts: the relative errors (COLUMNS), then the
    true b [m]; for the daemon's estimator also z = error / its sigma (SIGMAS); and its frame
    times [s]."""
    pad, device = SimTaxelPad(calibration, seed, noise_scale), TaxelArray(calibration)
    estimators = {name: make() for name, make in ESTIMATORS.items()}
    errors = {name: [] for name in estimators}
    z, times = [], []
    for k in range(int(impact.duration_s * FRAME_HZ)):
        t = (k + 0.5) / FRAME_HZ
        truth = impact.at(t)
        frame = device.pressures(pad.frame_volts(truth))
        found = {}
        for name, estimator in estimators.items():
            started = time.perf_counter()
            found[name] = estimator.update(frame)
            if name == OURS:
                times.append(time.perf_counter() - started)
        if trace is not None:
            trace.append((t, truth, found))
        if truth is None or truth.b < COUNTED_B_M:
            continue
        for name, est in found.items():
            if est is None:
                errors[name].append([np.nan] * len(COLUMNS) + [truth.b])
                continue
            errors[name].append([est.a / truth.a - 1, est.b / truth.b - 1, est.p_max / truth.p_max - 1,
                                 est.beta / truth.beta - 1, est.force_n / truth.force_n - 1,
                                 np.hypot(est.cx - truth.cx, est.cy - truth.cy) / truth.b, truth.b])
        ours = found[OURS]
        if ours is not None:
            z.append([(getattr(ours, p) - getattr(truth, p)) / getattr(ours, s) for p, s in zip(COLUMNS[:5], SIGMAS)])
    return {name: np.array(rows) for name, rows in errors.items()}, np.array(z), times


def first_counted_bound(impact: Impact, calibration, seed: int) -> tuple[float, float]:
    """(beta's 1-sigma bound at the first counted frame, relative, from every frame since first
    touch with the parameters on a straight line through the true ones and the sensor's
    noise; the daemon's estimator's own relative 1 sigma there)."""
    pad, device, grid = SimTaxelPad(calibration, seed), TaxelArray(calibration), SensingGrid()
    estimator, rows = ContactEstimator(), []
    for k in range(int(impact.duration_s * FRAME_HZ)):
        truth = impact.at((k + 0.5) / FRAME_HZ)
        frame = device.pressures(pad.frame_volts(truth))
        found = estimator.update(frame)
        region = contact_region(frame)
        if region is None:
            rows.clear()
            continue
        ring = dilate(region) & ~np.isnan(frame)
        true = to_levels(np.array([truth.cx * MM, truth.cy * MM, truth.a * MM, truth.b * MM,
                                   math.log(truth.p_max), truth.beta]))
        rows.append((k, levels_model(true, grid.px[ring], grid.py[ring])[1] / NOISE_PA))
        if truth.b >= COUNTED_B_M:
            rows_now = [np.hstack([jac, jac * (k0 - k)]) for k0, jac in rows]  # levels and rates now
            info = sum(h.T @ h for h in rows_now)
            own = found.beta_sd / truth.beta if found is not None else math.nan
            return math.sqrt(np.linalg.pinv(info)[5, 5]) / truth.beta, own
    return math.nan, math.nan


def merged_table(speed_runs: dict) -> list:
    """Rows (label, estimator, largest, RMS, 99.9th percentile, largest from 2.5 taxels, lost, frames)."""
    rows = []
    for label, merged in speed_runs.items():
        for name, parts in merged.items():
            every = np.concatenate(parts)
            e, b = np.abs(every[:, :-1]), every[:, -1]
            larger = b >= LARGER_TAXELS * PAD_M / TAXELS
            rows.append((label, name, np.nanmax(e, axis=0), np.sqrt(np.nanmean(e ** 2, axis=0)),
                         np.nanpercentile(e, 99.9, axis=0),
                         np.nanmax(e[larger], axis=0) if larger.any() else np.full(len(COLUMNS), np.nan),
                         int(np.isnan(e[:, 0]).sum()), len(e)))
    return rows


def print_tables(rows: list, first: str) -> None:
    print(f"\n| {first} | estimator | {' | '.join(f'{c} max / rms' for c in COLUMNS)} | frames lost |")
    print("|" + "---|" * (len(COLUMNS) + 3))
    for label, name, worst, rms, _, _, lost, n in rows:
        cells = " | ".join(f"{w * 100:.1f} / {r * 100:.1f} %" for w, r in zip(worst, rms))
        print(f"| {label} | {name} | {cells} | {lost} of {n} |")
    print(f"\nThe 99.9th percentile of each error, and the largest once the contact is {LARGER_TAXELS} taxels "
          "in b or more:\n")
    print(f"| {first} | estimator | {' | '.join(f'{c} p99.9 / from 2.5' for c in COLUMNS)} |")
    print("|" + "---|" * (len(COLUMNS) + 2))
    for label, name, _, _, p999, larger, _, _ in rows:
        print(f"| {label} | {name} | " + " | ".join(f"{p * 100:.1f} / {w * 100:.1f} %" for p, w in zip(p999, larger)) + " |")


def plot(path: str, trace: list) -> None:
    """Each estimator's relative error over one impact [%], the daemon's with its +-3 sigma,
    the frames that do not count (b under 2 taxels) shaded."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = np.array([row[0] for row in trace])
    counted = np.array([r[1] is not None and r[1].b >= COUNTED_B_M for r in trace])
    fig, axes = plt.subplots(2, 2, figsize=(12, 7.5), sharex=True)
    panels = [("a", "a_sd", 3.0, "semi-axis a"), ("p_max", "p_max_sd", 3.0, "peak pressure p_max"),
              ("beta", "beta_sd", 12.0, "shape exponent beta"), ("force_n", "force_sd_n", 3.0, "total force")]
    for ax, (key, sd_key, limit, label) in zip(axes.flat, panels):
        truth = np.array([getattr(r[1], key) if r[1] else np.nan for r in trace])
        for name, style in (("plain WLS", "C1."), ("S-WLS + RLS (paper)", "C2-"), (OURS, "C0-")):
            value = np.array([getattr(r[2][name], key) if r[2][name] else np.nan for r in trace])
            ax.plot(t, (value / truth - 1) * 100, style, ms=1.5, lw=1, label=name)
        sd = np.array([getattr(r[2][OURS], sd_key) if r[2][OURS] else np.nan for r in trace])
        ax.fill_between(t, -300 * sd / truth, 300 * sd / truth, color="C0", alpha=0.2, lw=0,
                        label="daemon's +-3 sigma (its own)")
        ax.fill_between(t, -limit, limit, where=~counted, color="0.85", lw=0, label="b under 2 taxels: not counted")
        ax.axhline(5, color="r", lw=0.8, ls="--")
        ax.axhline(-5, color="r", lw=0.8, ls="--", label="+-5 % (the goal)")
        ax.set_ylim(-limit, limit)
        ax.set_ylabel(f"{label}: relative error [%]")
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("time from first touch [s]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=6, fontsize=8.5, markerscale=4)
    fig.suptitle("An impact at 0.08 m/s on the 16 x 16 pad, 4 kHz frames: errors against the simulator's truth\n"
                 "(python -m bench.contact_force --plot)")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.contact_force", description=__doc__.splitlines()[0])
    ap.add_argument("--impacts", type=int, default=5, help="impacts per speed")
    ap.add_argument("--seed", type=int, default=0,
                    help="other impacts: each speed's are drawn from seed 1000 x speed + this (the tables' are 0)")
    ap.add_argument("--plot", default=None, help="write a PNG of one impact's estimates against the truth")
    ap.add_argument("--bound", action="store_true", help="beta's information bound at each first counted frame")
    ap.add_argument("--off-nominal", action="store_true", help="impacts of shapes the estimator was not tuned on")
    args = ap.parse_args(argv)
    header("contact estimators on simulated impacts: accuracy, uncertainty, and a frame's cost against 4 kHz")
    runs, zs, times = {}, [], []
    for speed in SPEEDS:
        merged = runs.setdefault(f"{speed} m/s", {})
        for impact, calibration, i in impacts(speed, args.impacts, seed=int(speed * 1000) + args.seed):
            errors, z, spent = run(impact, calibration, seed=i)
            zs.append(z)
            times += spent
            for name, e in errors.items():
                merged.setdefault(name, []).append(e)
    print_tables(merged_table(runs), "speed")
    z = np.concatenate(zs)
    print("\nThe daemon's estimator's own 1 sigma against its errors, z = error / sigma over the same frames:\n")
    print("| | " + " | ".join(COLUMNS[:5]) + " |")
    print("|" + "---|" * 6)
    print("| z RMS | " + " | ".join(f"{v:.2f}" for v in np.sqrt(np.mean(z ** 2, axis=0))) + " |")
    print("| within 3 sigma | " + " | ".join(f"{v * 100:.2f} %" for v in np.mean(np.abs(z) <= 3, axis=0)) + " |")
    print("| largest abs z | " + " | ".join(f"{v:.1f}" for v in np.abs(z).max(axis=0)) + " |")
    if args.bound:
        print("\nbeta's 1 sigma at each impact's first counted frame: the information bound and the daemon's "
              "estimator's own (relative):\n")
        for speed in SPEEDS:
            pairs = [first_counted_bound(imp, cal, i)
                     for imp, cal, i in impacts(speed, args.impacts, seed=int(speed * 1000) + args.seed)]
            print(f"- {speed} m/s: " + ", ".join(f"{b * 100:.1f} / {o * 100:.1f} %" for b, o in pairs))
    if args.off_nominal:
        off = {}
        for label, (changes, noise) in OFF_NOMINAL.items():
            merged = off.setdefault(label, {})
            for speed in (0.03, 0.11):
                for impact, calibration, i in impacts(speed, 4, seed=int(speed * 1000) + 500 + args.seed):
                    errors, _, _ = run(dataclasses.replace(impact, **changes), calibration, i, noise)
                    for name, e in errors.items():
                        merged.setdefault(name, []).append(e)
        print("\nImpacts the estimator was not tuned on (4 at 0.03 and 4 at 0.11 m/s each):")
        print_tables(merged_table(off), "impact")
    spent_us = np.array(times) * 1e6
    print(f"\n{OURS}, per frame: mean {spent_us.mean():.0f} us, p99 {np.percentile(spent_us, 99):.0f} us, "
          f"max {spent_us.max():.0f} us over {len(spent_us)} frames; a 4 kHz frame has 250 us "
          f"({spent_us.mean() / 250:.0%} of it on average)")
    if args.plot:
        trace = []
        impact, calibration, i = next(impacts(0.08, 1, seed=80))
        run(impact, calibration, i, trace=trace)
        plot(args.plot, trace)
        print(f"wrote {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(argv=None))
