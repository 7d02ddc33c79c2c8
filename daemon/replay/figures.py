"""The replay's pictures (matplotlib PNGs): per joint, the measured position against the
simulated one and the set-point, their difference with the limit where they part, and the
commands recorded against the commands the controller gave on the model."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def plot(result: dict, out: Path, title: str) -> list[Path]:
    """One PNG per joint in ``out``; their paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    t, written = result["t"], []
    for k, (joint, figures) in enumerate(result["joints"].items()):
        unit, scale = result["units"][joint]
        mine = [i for i, c in enumerate(result["commands"]) if c.startswith(f"{joint}.u.")]
        fig, axes = plt.subplots(3 if mine else 2, 1, sharex=True, figsize=(9, 8 if mine else 6))
        ax = axes[0]
        ax.plot(t, result["setpoints"][:, k] * scale, color="0.6", lw=1, ls="--", label="set-point (recorded)")
        ax.plot(t, result["measured"][:, k] * scale, lw=1.2, label="measured (the arm)")
        ax.plot(t, result["simulated"][:, k] * scale, lw=1.2, label="simulated (the model)")
        ax.set_ylabel(f"{joint} position [{unit}]")
        ax.legend(loc="best", fontsize=8)
        fit = figures["fit_percent"]
        ax.set_title(f"{title}: {joint}, Fit [2-49] {fit:.1f} %, controller {result['controller']}")
        ax = axes[1]
        ax.plot(t, (result["measured"][:, k] - result["simulated"][:, k]) * scale, lw=1, color="C3")
        limit = figures["part_limit"]
        for sign in (1, -1):
            ax.axhline(sign * limit, color="0.5", lw=0.8, ls=":")
        if figures["parted_s"] is not None:
            ax.axvline(figures["parted_s"], color="C3", lw=0.8, ls="--", label=f"parted at {figures['parted_s']:.2f} s")
            ax.legend(loc="best", fontsize=8)
        ax.set_ylabel(f"measured - simulated [{unit}]")
        if mine:
            ax = axes[2]
            for i in mine:
                name = result["commands"][i].split(".", 1)[1]
                ax.plot(t, result["recorded_u"][:, i], lw=1, label=f"{name} recorded")
                ax.plot(t, result["simulated_u"][:, i], lw=1, label=f"{name} on the model")
            ax.set_ylabel(f"command [{', '.join(sorted({result['command_units'][i] for i in mine}))}]")
            ax.legend(loc="best", fontsize=8)
        axes[-1].set_xlabel("time from the enable [s]")
        fig.tight_layout()
        path = out / f"replay-{joint}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        written.append(path)
    return written


def summary(result: dict) -> dict:
    """What the replay says in numbers (report.json)."""
    keep = {k: v for k, v in result.items()
            if not isinstance(v, np.ndarray) and k not in ("units", "commands", "command_units")}
    return keep
