"""The array sensor's contact estimator on simulated impacts (rig-facts §3): accuracy against
the simulator's truth, the paper's S-WLS + RLS against plain WLS on the same frames, and what
a frame costs against the sensor's 4 kHz.

    python -m bench.contact_force [--impacts 5] [--seed 0] [--plot docs/images/contact-impact.png]

For each of the paper's contact speeds (0.03, 0.08, 0.11 m/s), ``--impacts`` impacts with
their own centre, slide, pad (gain and offset spread, two dead taxels) and noise; errors are
taken on every frame where the true contact is at least two taxels (5 mm) across in b (a
smaller one is not resolved by a 2.5 mm pitch). The table gives the largest error over all
of them and the RMS, a second the largest once b is 2.5 taxels or more (the smallest
contacts' single frames carry the largest errors); the centre's miss is relative to b. Frame cost: the estimator alone,
one process, per frame over all impacts (mean and 99th percentile) against the 250 us a
frame has at 4 kHz.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from bench.common import header
from controllers.contact_force import ContactEstimator, PlainWLS
from hal.taxel_array import PAD_M, TAXELS, TaxelArray
from sim_backend.contact_patch import Impact, SimTaxelPad, spread_calibration

FRAME_HZ = 4000.0
SPEEDS = (0.03, 0.08, 0.11)
COLUMNS = ("a", "b", "p_max", "beta", "force_n", "centre")
LARGER_TAXELS = 2.5  # semi-axis b in taxels from which the second table counts


def impacts(speed: float, count: int, seed: int):
    """``count`` impacts at ``speed`` with their own centre, slide, pad and noise."""
    rng = np.random.default_rng(seed)
    for i in range(count):
        centre = tuple(rng.uniform(-0.004, 0.004, 2))
        slide = tuple(rng.uniform(-0.008, 0.008, 2))
        dead = tuple((int(r), int(c)) for r, c in rng.integers(4, 12, (2, 2)))
        yield Impact(speed, centre_m=centre, slide_m_s=slide, aspect=float(rng.uniform(0.7, 1.0)),
                     beta_peak=float(rng.uniform(0.6, 1.0))), spread_calibration(int(rng.integers(1 << 30)), dead), i


def run(impact: Impact, calibration, seed: int, trace: list | None = None):
    """Errors per estimator on the frames that count (each row: COLUMNS, then the true b
    [m]), and the S-WLS estimator's frame times."""
    pad, device = SimTaxelPad(calibration, seed), TaxelArray(calibration)
    estimators = {"S-WLS + RLS": ContactEstimator(), "plain WLS": PlainWLS()}
    errors = {name: [] for name in estimators}
    times = []
    for k in range(int(impact.duration_s * FRAME_HZ)):
        t = (k + 0.5) / FRAME_HZ
        truth = impact.at(t)
        frame = device.pressures(pad.frame_volts(truth))
        found = {}
        for name, estimator in estimators.items():
            started = time.perf_counter()
            found[name] = estimator.update(frame)
            if name == "S-WLS + RLS":
                times.append(time.perf_counter() - started)
        if trace is not None:
            trace.append((t, truth, found))
        if truth is None or truth.b < 2 * PAD_M / TAXELS:
            continue
        for name, est in found.items():
            if est is None:
                errors[name].append([np.nan] * len(COLUMNS) + [truth.b])
                continue
            errors[name].append([est.a / truth.a - 1, est.b / truth.b - 1, est.p_max / truth.p_max - 1,
                                 est.beta / truth.beta - 1, est.force_n / truth.force_n - 1,
                                 np.hypot(est.cx - truth.cx, est.cy - truth.cy) / truth.b, truth.b])
    return {name: np.array(rows) for name, rows in errors.items()}, times


def plot(path: str, trace: list) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = np.array([row[0] for row in trace])
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for ax, (key, scale, label) in zip(axes.flat, [("a", 1e3, "semi-axis a [mm]"), ("b", 1e3, "semi-axis b [mm]"),
                                                   ("p_max", 1e-3, "peak pressure p_max [kPa]"),
                                                   ("beta", 1.0, "shape exponent beta [-]")]):
        truth = [getattr(r[1], key) * scale if r[1] else np.nan for r in trace]
        ax.plot(t, truth, "k-", lw=2.5, label="truth (simulator)")
        for name, style in (("plain WLS", "C1."), ("S-WLS + RLS", "C0-")):
            ax.plot(t, [getattr(r[2][name], key) * scale if r[2][name] else np.nan for r in trace], style,
                    ms=2, lw=1, label=name)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("time from first touch [s]")
    axes[0, 0].legend(loc="lower center")
    fig.suptitle("An impact at 0.08 m/s on the 16 x 16 pad, 4 kHz frames (bench.contact_force)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.contact_force", description=__doc__.splitlines()[0])
    ap.add_argument("--impacts", type=int, default=5, help="impacts per speed")
    ap.add_argument("--seed", type=int, default=0,
                    help="other impacts: each speed's are drawn from seed 1000 x speed + this (the tables' are 0)")
    ap.add_argument("--plot", default=None, help="write a PNG of one impact's estimates against the truth")
    args = ap.parse_args(argv)
    header("contact estimator on simulated impacts: accuracy, and a frame's cost against 4 kHz")
    rows, times = [], []
    for speed in SPEEDS:
        merged = {}
        for impact, calibration, i in impacts(speed, args.impacts, seed=int(speed * 1000) + args.seed):
            errors, spent = run(impact, calibration, seed=i)
            times += spent
            for name, e in errors.items():
                merged.setdefault(name, []).append(e)
        for name, parts in merged.items():
            rows_all = np.concatenate(parts)
            e, b = np.abs(rows_all[:, :-1]), rows_all[:, -1]
            larger = b >= LARGER_TAXELS * PAD_M / TAXELS
            rows.append((speed, name, np.nanmax(e, axis=0), np.sqrt(np.nanmean(e ** 2, axis=0)),
                         np.nanmax(e[larger], axis=0) if larger.any() else np.full(len(COLUMNS), np.nan),
                         int(np.isnan(e[:, 0]).sum()), len(e)))
    print(f"\n| speed | estimator | {' | '.join(f'{c} max / rms' for c in COLUMNS)} | frames lost |")
    print("|" + "---|" * (len(COLUMNS) + 3))
    for speed, name, worst, rms, _, lost, n in rows:
        cells = " | ".join(f"{w * 100:.1f} / {r * 100:.1f} %" for w, r in zip(worst, rms))
        print(f"| {speed} m/s | {name} | {cells} | {lost} of {n} |")
    print(f"\nThe largest error once the contact is {LARGER_TAXELS} taxels across in b or more:\n")
    print(f"| speed | estimator | {' | '.join(COLUMNS)} |")
    print("|" + "---|" * (len(COLUMNS) + 2))
    for speed, name, _, _, larger, _, _ in rows:
        print(f"| {speed} m/s | {name} | " + " | ".join(f"{w * 100:.1f} %" for w in larger) + " |")
    spent_us = np.array(times) * 1e6
    print(f"\nS-WLS + RLS, per frame: mean {spent_us.mean():.0f} us, p99 {np.percentile(spent_us, 99):.0f} us, "
          f"max {spent_us.max():.0f} us over {len(spent_us)} frames; a 4 kHz frame has 250 us "
          f"({spent_us.mean() / 250:.0%} of it on average)")
    if args.plot:
        trace = []
        impact, calibration, i = next(impacts(0.08, 1, seed=80))
        run(impact, calibration, i, trace)
        plot(args.plot, trace)
        print(f"wrote {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
