"""Pictures of recordings (``pneumactl plot``): joint angles against their set-points,
tracking errors, V_MV and the chamber pressures, the tip path against the reference in the
workspace, the contact force, and the controller's internal signals. Several recordings
overlay in the same figures, one colour per run (a controller comparison).

Units on every axis: deg, V, MPa, mm, N, s (time from each run's first sample). The tip
path is the forward kinematics of the first two joints [2-7] with the recording's own link
lengths (``describe.arm``).

Nothing misleads: V_MV is drawn only where the controller's output was written (not where the
safe state was), between its limits drawn as lines; a path's approach/path boundary is marked
(the ``reference`` start event's ``approach_s``); the tip path shows its start and direction;
each internal signal's unit is the one its own controller declares; runs whose results are
identical are drawn once, named together in the legend ("pid = lti (identical)"), never one line
hidden under another; a hole in the data (cycles missing: telemetry a slow client lost) breaks
the lines and is shaded, "no data" in the legend with how many and how long (:func:`holes`),
never bridged by a straight ramp; and a recording that is cut says so on every figure.
"""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from daemon.recordings import reading as recording  # noqa: E402
from daemon.recordings.channels import signal_units  # noqa: E402

DEG = 180.0 / math.pi
BOUNDARY = dict(color="0.35", ls=":", lw=1.2)  # the approach/path boundary
LIMIT = dict(color="0.5", ls="--", lw=1.0)  # V_MV's limits
HOLE = dict(alpha=0.18, lw=0)  # a span with no data
CUT = dict(color="firebrick", fontsize=8.5, ha="center", va="bottom")  # the note on a cut recording's figures


def _label(path: Path, run: recording.Run) -> str:
    return f"{path.stem} ({run.controller.get('name', '?')})"


def _time(run: recording.Run) -> np.ndarray:
    t = np.array([s["t"] for s in run.samples], dtype=float)
    return t - t[0] if len(t) else t


def _column(run: recording.Run, joint: str, key: str) -> np.ndarray:
    return np.array([s["joints"][joint][key] for s in run.samples], dtype=float)


def holes(run: recording.Run) -> list[tuple[float, float, int]]:
    """Where the state stream has no data: two samples in a row whose cycles are not (telemetry
    lost on its way, e.g. to a slow client), as (the sample before [s], the sample after [s],
    cycles missing), times from the run's first sample."""
    cycles = np.array([s["cycle"] for s in run.samples], dtype=np.int64)
    t = _time(run)
    return [(float(t[i]), float(t[i + 1]), int(cycles[i + 1] - cycles[i] - 1))
            for i in np.flatnonzero(np.diff(cycles) > 1)]


def _broken(run: recording.Run, values: np.ndarray) -> np.ndarray:
    """A state column (or the time) with a NaN in each hole: a drawn line stops there."""
    cycles = np.array([s["cycle"] for s in run.samples], dtype=np.int64)
    return np.insert(np.asarray(values, dtype=float), np.flatnonzero(np.diff(cycles) > 1) + 1, np.nan)


def _hole_words(found: list[tuple[float, float, int]]) -> str:
    total = sum(b - a for a, b, _ in found)
    return f"{len(found)} hole{'s' if len(found) > 1 else ''}, {total:.2f} s"


def hole_notes(name: str, run: recording.Run) -> list[str]:
    """What the figures of a run with holes show, in words (none without holes)."""
    found = holes(run)
    if not found:
        return []
    each = ", ".join(f"{b - a:.2f} s at {a:.2f} s" for a, b, _ in found[:10]) + (" ..." if len(found) > 10 else "")
    return [f"{name}: no data in {_hole_words(found)} in all ({each}; {sum(n for *_, n in found)} cycles missing): "
            f"drawn as gaps, shaded"]


def _shade_holes(ax, runs, colours) -> None:
    """Each run's holes as shaded spans, one legend entry per run ("no data")."""
    for colour, (label, run) in zip(colours, runs):
        found = holes(run)
        for k, (a, b, _) in enumerate(found):
            name = f"no data ({_hole_words(found)})" if len(runs) == 1 else f"{label}: no data ({_hole_words(found)})"
            ax.axvspan(a, b, color="0.45" if len(runs) == 1 else colour, **HOLE, label=name if k == 0 else None)


def merge_identical(labels: list[str], arrays: list, within: float = 0.0) -> list[tuple[str, int]]:
    """Runs whose data are identical, drawn once: (label, index of the run to draw), the label
    naming every run it stands for ("pid = lti (identical)"). ``within`` > 0: runs whose every
    column differs by at most this fraction of its range, which a figure cannot tell apart
    (one line would hide the other), are merged too, and the label says so
    ("pid ≈ lti (within 1 % of the range)")."""
    groups: list[list[int]] = []
    for i, a in enumerate(arrays):
        for group in groups:
            if _same(np.asarray(arrays[group[0]], dtype=float), np.asarray(a, dtype=float), within):
                group.append(i)
                break
        else:
            groups.append([i])
    merged = []
    for g in groups:
        exact = all(np.array_equal(np.asarray(arrays[g[0]]), np.asarray(arrays[i]), equal_nan=True) for i in g)
        note = "" if len(g) == 1 else " (identical)" if exact else f" (within {within:.0%} of the range)"
        merged.append(((" = " if exact else " ≈ ").join(labels[i] for i in g) + note, g[0]))
    return merged


def _same(a: np.ndarray, b: np.ndarray, within: float) -> bool:
    if a.shape != b.shape:
        return False
    if np.array_equal(a, b, equal_nan=True):
        return True
    if within <= 0 or a.size == 0:
        return False
    a2, b2 = a.reshape(len(a), -1), b.reshape(len(b), -1)
    span = np.nanmax(a2, axis=0) - np.nanmin(a2, axis=0)
    return bool(np.all(np.nanmax(np.abs(a2 - b2), axis=0) <= within * np.maximum(span, 1e-12)))


def _distinct(runs):
    """The runs to draw: identical ones (every joint's angle and V_MV) merged."""
    arrays = [np.array([[s["joints"][j]["angle_rad"] for j in run.joints] + [s["joints"][j]["u_volts"] for j in run.joints]
                        for s in run.samples]) for _, run in runs]
    return [(label, runs[i][1]) for label, i in merge_identical([label for label, _ in runs], arrays)]


def path_starts(run: recording.Run) -> list[float]:
    """Where each path began after its approach [s from the run's first sample]: its
    ``reference`` event ``settled`` (the daemon holds the path's start until the arm has settled
    there), or, in recordings made before the daemon waited, the start event's time plus its
    ``approach_s`` (recordings before that: none)."""
    t0, period = run.samples[0]["t"], run.describe.get("period_s", 0.001)
    events = [e for e in run.messages.get("event", []) if e.get("kind") == "reference"]
    settled = {e.get("generation"): e["t"] for e in events if e.get("action") == "settled"}
    return [settled.get(e.get("generation"), e["t"] + period + e["approach_s"]) - t0 for e in events
            if e.get("action") == "start" and e.get("approach_s") is not None]


def _per_joint_figure(runs, title: str, ylabel: str, draw) -> plt.Figure:
    joints = runs[0][1].joints
    fig, axes = plt.subplots(len(joints), 1, figsize=(10, 3.2 * len(joints)), sharex=True, squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"] * 4
    for ax, joint in zip(axes[:, 0], joints):
        for colour, (label, run) in zip(colours, runs):
            if joint in run.joints:
                draw(ax, joint, label, run, colour)
        _shade_holes(ax, runs, colours)
        for k, t in enumerate(sorted({t for _, run in runs for t in path_starts(run)})):
            ax.axvline(t, **BOUNDARY, label="approach ends, path begins" if k == 0 else None)
        ax.set_title(f"{joint} joint")
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def _angles(ax, joint, label, run, colour):
    t = _broken(run, _time(run))
    ax.plot(t, _broken(run, _column(run, joint, "setpoint_rad") * DEG), "--", color=colour, lw=1.0,
            label=f"{label} set-point")
    ax.plot(t, _broken(run, _column(run, joint, "angle_rad") * DEG), color=colour, lw=1.4, label=f"{label} angle")


def _errors(ax, joint, label, run, colour):
    ax.plot(_broken(run, _time(run)), _broken(run, _column(run, joint, "error_rad") * DEG), color=colour, lw=1.2,
            label=label)


def _outputs(ax, joint, label, run, colour):
    """V_MV where the controller's output was written (outside ``enabled`` the safe state was:
    no V_MV is drawn there), and the joint's V_MV limits."""
    u = _column(run, joint, "u_volts")
    u[np.array([s["mode"] != "enabled" for s in run.samples])] = np.nan
    ax.plot(_broken(run, _time(run)), _broken(run, u), color=colour, lw=1.2, label=f"{label} V_MV")
    spec = next((j for j in run.describe["joints"] if j["name"] == joint), {})
    limits = [spec[k] for k in ("u_min_volts", "u_max_volts") if spec.get(k) is not None]
    drawn = {line.get_label() for line in ax.get_lines()}
    for k, v in enumerate(limits):
        ax.axhline(v, **LIMIT, label="V_MV limits" if k == 0 and "V_MV limits" not in drawn else None)


def _pressures(ax, joint, label, run, colour):
    t = _broken(run, _time(run))
    ax.plot(t, _broken(run, _column(run, joint, "p_head_pa") / 1e6), color=colour, lw=1.2, label=f"{label} head")
    ax.plot(t, _broken(run, _column(run, joint, "p_rod_pa") / 1e6), ":", color=colour, lw=1.2, label=f"{label} rod")


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
            ax.plot(_broken(run, x), _broken(run, y), style, color=colour, lw=1.0 if what == "reference" else 1.4,
                    label=f"{label} {what}")
            if what == "reference":
                start_and_direction(ax, x, y, _time(run), path_starts(run), colour, label)
        found = holes(run)
        if found:  # (no time axis to shade: said in the legend, the lines broken)
            ax.plot([], [], " ", label=f"{label if len(runs) > 1 else ''} no data ({_hole_words(found)}): lines broken".strip())
        drawn = True
    ax.set_aspect("equal", adjustable="datalim")
    return _finish(fig, ax, drawn, "x [mm]", "y [mm]", "tip path in the workspace (forward kinematics of the first two joints)")


def start_and_direction(ax, x, y, t, starts: list[float], colour, label: str) -> None:
    """The reference's start (a circle), where the path begins after its approach (a square),
    and arrows along it, so a reader sees where it starts and which way it runs."""
    ax.plot(x[:1], y[:1], "o", color=colour, ms=7, mfc="none", mew=1.6, label=f"{label} start")
    for k, ts in enumerate(starts):
        i = min(int(np.searchsorted(t, ts)), len(x) - 1)
        ax.plot(x[i:i + 1], y[i:i + 1], "s", color=colour, ms=7, mfc="none", mew=1.6,
                label=f"{label} path begins (approach ends)" if k == 0 else None)
    step = np.hypot(np.diff(x), np.diff(y))
    along = np.concatenate([[0.0], np.cumsum(step)])
    if along[-1] <= 0:
        return
    for f in (0.15, 0.4, 0.65, 0.9):  # arrows at fractions of the length drawn
        i = min(int(np.searchsorted(along, f * along[-1])), len(x) - 2)
        j = min(i + max(len(x) // 200, 1), len(x) - 1)
        if (x[j], y[j]) != (x[i], y[i]):
            ax.annotate("", xy=(x[j], y[j]), xytext=(x[i], y[i]),
                        arrowprops=dict(arrowstyle="-|>", color=colour, lw=1.2, mutation_scale=16))


def _force(runs) -> plt.Figure | None:
    fig, ax = plt.subplots(figsize=(10, 3.5))
    drawn = False
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"] * 4
    for colour, (label, run) in zip(colours, runs):
        force = np.array([s["force_n"] for s in run.samples], dtype=float)
        if np.isfinite(force).any():
            ax.plot(_broken(run, _time(run)), _broken(run, force), color=colour, lw=1.2, label=label)
            drawn = True
    if drawn:
        _shade_holes(ax, runs, colours)
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
    units: dict[str, set[str]] = {}  # each signal's unit, from the controller that published it
    for m in messages:
        declared = signal_units(run.describe, m.get("controller", ""))
        for name in m["signals"]:
            units.setdefault(name, set()).add(declared.get(name, "-"))
    t0 = run.samples[0]["t"] if run.samples else messages[0]["t"]
    names = list(messages[-1]["signals"])
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 2.4 * len(names)), sharex=True, squeeze=False)
    seq = np.array([m.get("seq", k) for k, m in enumerate(messages)], dtype=np.int64)
    lost = np.flatnonzero(np.diff(seq) > 1) + 1  # messages lost between these: the lines stop there
    t = np.insert(np.array([m["t"] for m in messages], dtype=float) - t0, lost, np.nan)
    for ax, name in zip(axes[:, 0], names):
        for j, joint in enumerate(run.joints):
            values = [m["signals"][name][j] if name in m["signals"] else np.nan for m in messages]
            ax.plot(t, np.insert(np.array(values, dtype=float), lost, np.nan), lw=1.1, label=joint)
        _shade_holes(ax, [(label, run)], ["0.45"])
        ax.set_ylabel(f"{name} [{' | '.join(sorted(units.get(name, {'-'})))}]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"controller internals: {label}")
    fig.tight_layout()
    return fig


def figures(runs: list[tuple[str, recording.Run]]) -> dict[str, plt.Figure | None]:
    """Every figure of the runs ((label, run) each), by name; None where there is nothing to draw."""
    drawn = _distinct(runs)
    made = {"joints": _per_joint_figure(drawn, "joint angles and set-points", "angle [deg]", _angles),
            "errors": _per_joint_figure(drawn, "tracking error (set-point - angle)", "error [deg]", _errors),
            "output": _per_joint_figure(drawn, "controller output V_MV (head chamber above its bias; none drawn "
                                               "where the safe state was written)", "V_MV [V]", _outputs),
            "pressures": _per_joint_figure(drawn, "chamber pressure commands", "pressure [MPa]", _pressures),
            "tip": _tip(drawn), "force": _force(drawn)}
    for i, (label, run) in enumerate(runs):
        made[f"internals{'-' + str(i + 1) if len(runs) > 1 else ''}"] = _internals(label, run)
    return made


def open_runs(paths) -> list[recording.Run]:
    """The recordings to plot, read (ValueError for one with no state sample)."""
    runs = []
    for f in paths:
        run = recording.open_run(f)
        if not run.samples:
            raise ValueError(f"{f}: no state samples to plot")
        runs.append(run)
    return runs


def _say_cut(fig: plt.Figure, notices: list[str]) -> None:
    """A cut recording's notice at the foot of a figure, room made for it."""
    import textwrap
    width, height = fig.get_size_inches()
    lines = [line for notice in notices for line in textwrap.wrap(notice, int(13 * width))]
    room = (0.16 * len(lines) + 0.1) / height  # [fraction of the figure]
    fig.subplots_adjust(bottom=fig.subplotpars.bottom + room)
    fig.text(0.5, 0.06 / height, "\n".join(lines), **CUT)


def plot_runs(paths, out_dir=".", runs: list[recording.Run] | None = None) -> list[Path]:
    """Write the figures of one or more recordings into ``out_dir`` (``runs``: those at
    ``paths``, opened already); the files written."""
    files = [Path(p) for p in paths]
    runs = open_runs(files) if runs is None else runs
    notices = [run.cut_notice(f.name) for f, run in zip(files, runs) if run.truncated]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = files[0].stem if len(files) == 1 else "compare"
    written = []
    for name, fig in figures([(_label(f, run), run) for f, run in zip(files, runs)]).items():
        if fig is None:
            continue
        if notices:
            _say_cut(fig, notices)
        target = out / f"{stem}-{name}.png"
        fig.savefig(target, dpi=110)
        plt.close(fig)
        written.append(target)
    return written
