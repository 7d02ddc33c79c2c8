"""Pictures of recordings (``pneumactl plot``): joint angles against their set-points,
tracking errors, V_MV and the chamber pressures, the tip path against the reference in the
workspace, the contact force, and the controller's internal signals. Several recordings
overlay in the same figures, one colour per run (a controller comparison).

Units on every axis: deg, V, MPa, mm, N, s (time from each run's first sample). The tip
path is the forward kinematics of the first two joints [2-7] with the recording's own link
lengths (``describe.arm``).
"""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from daemon.recordings import reading as recording  # noqa: E402

DEG = 180.0 / math.pi


def _label(path: Path, run: recording.Run) -> str:
    return f"{path.stem} ({run.controller.get('name', '?')})"


def _time(run: recording.Run) -> np.ndarray:
    t = np.array([s["t"] for s in run.samples], dtype=float)
    return t - t[0] if len(t) else t


def _column(run: recording.Run, joint: str, key: str) -> np.ndarray:
    return np.array([s["joints"][joint][key] for s in run.samples], dtype=float)


def _per_joint_figure(runs, title: str, ylabel: str, draw) -> plt.Figure:
    joints = runs[0][1].joints
    fig, axes = plt.subplots(len(joints), 1, figsize=(10, 3.2 * len(joints)), sharex=True, squeeze=False)
    for ax, joint in zip(axes[:, 0], joints):
        for colour, (label, run) in zip(plt.rcParams["axes.prop_cycle"].by_key()["color"] * 4, runs):
            if joint in run.joints:
                draw(ax, joint, label, run, colour)
        ax.set_title(f"{joint} joint")
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def _angles(ax, joint, label, run, colour):
    t = _time(run)
    ax.plot(t, _column(run, joint, "setpoint_rad") * DEG, "--", color=colour, lw=1.0, label=f"{label} set-point")
    ax.plot(t, _column(run, joint, "angle_rad") * DEG, color=colour, lw=1.4, label=f"{label} angle")


def _errors(ax, joint, label, run, colour):
    ax.plot(_time(run), _column(run, joint, "error_rad") * DEG, color=colour, lw=1.2, label=label)


def _outputs(ax, joint, label, run, colour):
    ax.plot(_time(run), _column(run, joint, "u_volts"), color=colour, lw=1.2, label=f"{label} V_MV")


def _pressures(ax, joint, label, run, colour):
    t = _time(run)
    ax.plot(t, _column(run, joint, "p_head_pa") / 1e6, color=colour, lw=1.2, label=f"{label} head")
    ax.plot(t, _column(run, joint, "p_rod_pa") / 1e6, ":", color=colour, lw=1.2, label=f"{label} rod")


def _tip(runs) -> plt.Figure | None:
    fig, ax = plt.subplots(figsize=(7, 7))
    drawn = False
    for colour, (label, run) in zip(plt.rcParams["axes.prop_cycle"].by_key()["color"] * 4, runs):
        lengths = run.describe["arm"]["link_lengths_mm"]
        if len(run.joints) < 2 or len(lengths) < 2:
            continue
        a, b = run.joints[:2]
        for key, style, what in (("setpoint_rad", "--", "reference"), ("angle_rad", "-", "tip")):
            q1, q2 = _column(run, a, key), _column(run, b, key)
            x = lengths[0] * np.cos(q1) + lengths[1] * np.cos(q1 + q2)
            y = lengths[0] * np.sin(q1) + lengths[1] * np.sin(q1 + q2)
            ax.plot(x, y, style, color=colour, lw=1.0 if what == "reference" else 1.4, label=f"{label} {what}")
        drawn = True
    ax.set_aspect("equal", adjustable="datalim")
    return _finish(fig, ax, drawn, "x [mm]", "y [mm]", "tip path in the workspace (forward kinematics of the first two joints)")


def _force(runs) -> plt.Figure | None:
    fig, ax = plt.subplots(figsize=(10, 3.5))
    drawn = False
    for label, run in runs:
        force = np.array([s["force_n"] for s in run.samples], dtype=float)
        if np.isfinite(force).any():
            ax.plot(_time(run), force, lw=1.2, label=label)
            drawn = True
    return _finish(fig, ax, drawn, "time [s]", "force [N]", "tip force")


def _finish(fig, ax, drawn: bool, xlabel: str, ylabel: str, title: str) -> plt.Figure | None:
    """Labels, grid and legend on a one-axes figure; None (and the figure closed) if nothing was drawn."""
    if not drawn:
        plt.close(fig)
        return None
    ax.set(xlabel=xlabel, ylabel=ylabel, title=title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    return fig


def _internals(label: str, run: recording.Run) -> plt.Figure | None:
    """One run's internal signals, a subplot per signal, a line per joint."""
    messages = run.messages.get("internals", [])
    if not messages:
        return None
    units = {s["name"]: s["unit"] for c in run.describe.get("controllers", []) if isinstance(c, dict)
             for s in c.get("internals", [])}
    t0 = run.samples[0]["t"] if run.samples else messages[0]["t"]
    names = list(messages[-1]["signals"])
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 2.4 * len(names)), sharex=True, squeeze=False)
    t = np.array([m["t"] for m in messages]) - t0
    for ax, name in zip(axes[:, 0], names):
        for j, joint in enumerate(run.joints):
            values = [m["signals"][name][j] if name in m["signals"] else np.nan for m in messages]
            ax.plot(t, values, lw=1.1, label=joint)
        ax.set_ylabel(f"{name} [{units.get(name, '-')}]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"controller internals: {label}")
    fig.tight_layout()
    return fig


def plot_runs(paths, out_dir=".") -> list[Path]:
    """Write the figures of one or more recordings into ``out_dir``; the files written."""
    files = [Path(p) for p in paths]
    runs = []
    for f in files:
        run = recording.open_run(f)
        if not run.samples:
            raise ValueError(f"{f}: no state samples to plot")
        runs.append((_label(f, run), run))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = files[0].stem if len(files) == 1 else "compare"
    figures = {"joints": _per_joint_figure(runs, "joint angles and set-points", "angle [deg]", _angles),
               "errors": _per_joint_figure(runs, "tracking error (set-point - angle)", "error [deg]", _errors),
               "output": _per_joint_figure(runs, "controller output V_MV (head chamber above its bias)", "V_MV [V]",
                                           _outputs),
               "pressures": _per_joint_figure(runs, "chamber pressure commands", "pressure [MPa]", _pressures),
               "tip": _tip(runs), "force": _force(runs)}
    for i, (label, run) in enumerate(runs):
        figures[f"internals{'-' + str(i + 1) if len(runs) > 1 else ''}"] = _internals(label, run)
    written = []
    for name, fig in figures.items():
        if fig is None:
            continue
        target = out / f"{stem}-{name}.png"
        fig.savefig(target, dpi=110)
        plt.close(fig)
        written.append(target)
    return written
