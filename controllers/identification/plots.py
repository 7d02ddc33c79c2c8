"""Figures of an identification: the measured frequency response with its coherence against
the fitted and the prior model (Bode), and the measured angle against both models' simulated
angle on each experiment (the held-out one first). PNG files, units on every axis."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from controllers.identification import frf  # noqa: E402
from controllers.identification.fit import Experiment, best_c, fit_percent, predict  # noqa: E402
from controllers.identification.simulate import samples_per_step  # noqa: E402
from hal.identified import JointParams  # noqa: E402

COHERENT = 0.8  # points with coherence below this are drawn faint


def bode(path: Path, joint: str, measured: list[tuple[str, frf.Response]], models: list[tuple[str, JointParams]],
         band: tuple[float, float]) -> Path:
    """Magnitude [dB re 1 deg/V], phase [deg] and coherence against frequency [Hz]."""
    fig, (mag, phase, coh) = plt.subplots(3, 1, figsize=(8, 9), sharex=True,
                                          gridspec_kw={"height_ratios": [3, 2, 1.2]})
    f_all = np.concatenate([r.f for _, r in measured]) if measured else np.geomspace(*band, 10)
    f_model = np.geomspace(max(f_all.min(), 0.02), f_all.max(), 400)
    for (label, r), colour in zip(measured, ("tab:blue", "tab:orange", "tab:purple")):
        good = r.coherence >= COHERENT
        db = 20 * np.log10(np.abs(r.g))
        ph = np.degrees(np.unwrap(np.angle(r.g)))
        for ax, values in ((mag, db), (phase, ph)):
            ax.semilogx(r.f[good], values[good], ".", color=colour, label=f"{label} ({r.method}), coherence >= {COHERENT}"
                        if ax is mag else None)
            ax.semilogx(r.f[~good], values[~good], ".", color=colour, alpha=0.2)
        coh.semilogx(r.f, r.coherence, ".-", color=colour, lw=0.8)
    for (label, params), style in zip(models, ("k-", "r--")):
        g = frf.model(params, f_model)
        mag.semilogx(f_model, 20 * np.log10(np.abs(g)), style, label=label)
        phase.semilogx(f_model, np.degrees(np.unwrap(np.angle(g))), style)
    for ax in (mag, phase, coh):
        ax.axvspan(*band, color="0.9", zorder=0)
        ax.grid(True, which="both", alpha=0.3)
    mag.set_ylabel("|G| [dB re 1 deg/V]")
    phase.set_ylabel("phase [deg]")
    coh.set_ylabel("coherence [-]")
    coh.set_ylim(0, 1.05)
    coh.set_xlabel("frequency [Hz]")
    mag.set_title(f"joint {joint}: V_MV -> angle (shaded: the {band[0]:g}-{band[1]:g} Hz band)")
    mag.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def time_overlay(path: Path, joint: str, runs: list[tuple[str, Experiment]], models: list[tuple[str, JointParams]],
                 step: float, c_bound: float) -> Path:
    """One panel per experiment: measured angle change [deg] and each model's simulation (from
    the start's best held friction torque within +-``c_bound`` [N m]), the [2-49] Fit % in the legend."""
    fig, axes = plt.subplots(len(runs), 1, figsize=(10, 3.2 * len(runs)), squeeze=False)
    for ax, (label, data) in zip(axes[:, 0], runs):
        m = samples_per_step(step, data.dt)
        target, t = data.y[m::m], data.t[m::m]
        ax.plot(t, target, color="0.3", lw=1.0, label="measured")
        for (name, params), style in zip(models, ("tab:red", "tab:green")):
            y_hat = predict(params, data, step, best_c(params, data, step, c_bound))[:len(target)]
            ax.plot(t[:len(y_hat)], y_hat, color=style, lw=1.0,
                    label=f"{name}: Fit {fit_percent(target[:len(y_hat)], y_hat):.1f} %")
        ax.set_title(label, fontsize=10)
        ax.set_ylabel(f"{joint} angle change [deg]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel("time from the experiment's start [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def run_overlay(path: Path, joint: str, data: Experiment, split_s: float,
                models: list[tuple[str, np.ndarray, float]], step: float) -> Path:
    """A closed-loop run: the measured angle change [deg], each model's (label, angle on the
    step grid [deg], Fit on the held-out tail [%]) and the line between the fitted part and the
    held-out one at ``split_s`` [s]."""
    m = samples_per_step(step, data.dt)
    target, t = data.y[m::m], data.t[m::m]
    fig, ax = plt.subplots(figsize=(10, 4.0))
    ax.plot(t, target, color="0.3", lw=1.0, label="measured")
    for (name, y_hat, fit), style in zip(models, ("tab:red", "tab:green")):
        ax.plot(t[:len(y_hat)], y_hat[:len(t)], color=style, lw=1.0, label=f"{name}: held-out Fit {fit:.1f} %")
    ax.axvline(split_s, color="0.5", ls="--", lw=1.0)
    ax.text(split_s, ax.get_ylim()[1], " held out ->", va="top", fontsize=8, color="0.4")
    ax.set_title(f"joint {joint}: the recorded run, fitted before the line, held out after it", fontsize=10)
    ax.set_ylabel(f"{joint} angle change [deg]")
    ax.set_xlabel("time from the run's start [s]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=3)  # below: the run fills the axes
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
