"""An evaluation's results: the table (Markdown), every case (CSV) and figures (PNG)."""
from __future__ import annotations

import csv
import math
from dataclasses import asdict, fields
from pathlib import Path

from evaluation.runner import BAND_DEG, HOLD_S, RECOVER_S, Case

COLUMNS = [f.name for f in fields(Case) if f.name != "trace"]


def write_csv(cases: list[Case], path: Path) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows({k: v for k, v in asdict(c).items() if k != "trace"} for c in cases)


def _worst(group: list[Case], attr: str) -> float:
    values = [getattr(c, attr) for c in group if not c.tripped]
    return max(values, default=math.nan)


def summary(cases: list[Case], controllers: list[str]) -> str:
    """One row per controller and reference: the first plant's figures, the worst over the plants, counts."""
    lines = ["| controller | reference | tip max first plant (mm) | tip max worst (mm) | tip RMS worst (mm) "
             "| joint max worst (deg) | joint RMS worst (deg) | at limit worst (%) | activity worst (V/s) "
             "| sign changes worst (1/s) | settling worst (s) | recovered | tripped |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    references = list(dict.fromkeys(c.reference for c in cases))
    for controller in controllers:
        for reference in references:
            group = [c for c in cases if (c.controller, c.reference) == (controller, reference)]
            if not group:
                continue
            first = group[0]
            settle = [c.settle_s for c in group if not c.tripped]
            worst_settle = "never" if any(math.isnan(s) for s in settle) else f"{max(settle, default=math.nan):.2f}"
            lines.append(f"| {controller} | {reference} {first.duration_s:.1f} s | {first.tip_max_mm:.2f} "
                         f"| {_worst(group, 'tip_max_mm'):.2f} | {_worst(group, 'tip_rms_mm'):.2f} "
                         f"| {_worst(group, 'joint_max_deg'):.2f} | {_worst(group, 'joint_rms_deg'):.2f} "
                         f"| {_worst(group, 'at_limit_pct'):.1f} | {_worst(group, 'motion_v_s'):.1f} "
                         f"| {_worst(group, 'sign_changes_per_s'):.1f} | {worst_settle} "
                         f"| {sum(c.recovered for c in group)}/{len(group)} "
                         f"| {sum(bool(c.tripped) for c in group)}/{len(group)} |")
    return "\n".join(lines)


def failures(cases: list[Case]) -> list[str]:
    """A line per case that tripped (with the supervisor's cause) or did not settle."""
    out = []
    for c in cases:
        if c.tripped:
            out.append(f"- {c.controller}, {c.reference}, {c.plant}: tripped ({c.tripped})")
        elif not c.recovered:
            out.append(f"- {c.controller}, {c.reference}, {c.plant}: not within {BAND_DEG:g} deg within "
                       f"{RECOVER_S:g} s of the end; {c.final_deg:.2f} deg after {HOLD_S:g} s")
    return out


def figures(cases: list[Case], controllers: list[str], joints: list[str], out: Path) -> list[Path]:
    """``summary.png`` (tip max per reference and controller: the first plant's and the worst)
    and, per reference, ``<reference>.png``: each controller's joint errors over time on the
    first plant (the traced cases)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    references = list(dict.fromkeys(c.reference for c in cases))
    fig, ax = plt.subplots(figsize=(min(14.0, 3.0 + 0.25 * len(references) * max(len(controllers), 2)), 4.5))
    width = 0.8 / max(len(controllers), 1)
    for k, controller in enumerate(controllers):
        xs, first, worst = [], [], []
        for r, reference in enumerate(references):
            group = [c for c in cases if (c.controller, c.reference) == (controller, reference)]
            if group:
                xs.append(r + (k - (len(controllers) - 1) / 2) * width)
                first.append(group[0].tip_max_mm)
                worst.append(_worst(group, "tip_max_mm"))
        bars = ax.bar(xs, worst, width * 0.9, label=f"{controller} (worst plant)", alpha=0.55)
        ax.plot(xs, first, "o", color=bars.patches[0].get_facecolor() if bars.patches else None,
                markeredgecolor="black", label=f"{controller} (first plant)")
    ax.set_xticks(range(len(references)), references, rotation=15)
    ax.set_ylabel("tip error, max [mm]")
    ax.set_yscale("log")
    ax.set_title("Tip error, max: first plant (dots), worst plant that ran (bars)", fontsize=10)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    path = out / "summary.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(path)
    for reference in references:
        traced = [c for c in cases if c.reference == reference and c.trace]
        if not traced:
            continue
        n = len(traced[0].trace["error_deg"][0])
        fig, axes = plt.subplots(n, 1, sharex=True, figsize=(8.0, 2.2 * n + 0.8), squeeze=False)
        for c in traced:
            for j in range(n):
                axes[j][0].plot(c.trace["t"], [e[j] for e in c.trace["error_deg"]], lw=0.9, label=c.controller)
        for j in range(n):
            axes[j][0].axvline(traced[0].duration_s, color="grey", ls="--", lw=0.8)
            axes[j][0].set_ylabel(f"{joints[j]} error [deg]")
            axes[j][0].grid(True, alpha=0.3)
        axes[0][0].legend(fontsize=7, ncol=3)
        axes[0][0].set_title(f"{reference} on the plant '{traced[0].plant}' (dashed: the reference's end)")
        axes[-1][0].set_xlabel("time from the reference's start [s]")
        fig.tight_layout()
        path = out / f"{reference.replace('/', '_').replace(' ', '-')}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written
