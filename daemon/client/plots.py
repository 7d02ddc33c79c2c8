"""Pictures of recordings (``pneumactl plot``): each joint's position against its set-point,
the tracking errors, the commands, the chamber pressures (commanded and measured, named
apart) and the joints' further inputs, the rig's own sensors, the tip path against the
reference in the workspace, and the controller's internal signals. Several recordings overlay
in the same figures, one colour per run (a controller comparison).

Every series, its name and its unit come from the recording's cycle record layout (``Run.layout``):
a rig with other joints or sensors is drawn as it is, with no code of its own. Values are shown
in each field's display unit (a rotary joint in deg, a linear one in mm, pressures in kPa, else the
SI unit) and
every axis says its unit; time is from each run's first sample, or, overlaying runs of paths,
from each run's path start (the path's own t = 0; the approach before it at negative times), so
runs that started their paths at different times line up. The tip path is the forward
kinematics of the first two joints (rotary) [2-7] with the recording's own link lengths
(``describe.arm``).

Nothing misleads (:mod:`daemon.client.plot_marks`): a command is drawn only where it was
written (not where the safe state was), between its limits drawn as lines; a path's
approach/path boundary is marked (its ``reference`` event ``settled``); the tip path shows its
start and direction; each internal signal's unit is the one its own controller declares (shown
in its display unit where every run's controller declares the same); runs
whose results are identical are drawn once, named together in the legend ("pid = lti
(identical)"), never one line hidden under another; a hole in the data (cycles missing:
telemetry a slow client lost) breaks the lines and is shaded, "no data" in the legend with how
many and how long, never bridged by a straight ramp; and a recording that is cut says so on
every figure.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from daemon.client import fields  # noqa: E402
from daemon.client.plot_marks import (BOUNDARY, degraded_sentence, degraded_spans, hole_sentence,  # noqa: E402
                                      hole_words, holes_of, merge_identical, path_starts, say_cut, shade_degraded,
                                      shade_holes, start_and_direction)
from daemon.recordings import reading as recording  # noqa: E402
from daemon.recordings.channels import signal_units  # noqa: E402
from hal.interfaces import DISPLAY  # noqa: E402

LIMIT = dict(color="0.5", ls="--", lw=1.0)  # a command's limits


class Drawn:
    """One run as the figures draw it: its label, its columns through its layout, its times
    (from ``t0``: its first sample, or its path's start when runs are aligned on it), its holes
    and where each path begins."""

    def __init__(self, label: str, run: recording.Run, align: bool = False):
        self.label, self.run, self.layout = label, run, run.layout
        self._columns: dict[str, np.ndarray] = {}
        t = self.column("t")
        self.cycles = np.asarray(run.column("cycle"), dtype=np.int64)
        self.breaks = np.flatnonzero(np.diff(self.cycles) > 1) + 1  # a NaN goes in before each: lines stop there
        starts = path_starts(run.describe, run.messages.get("event", []), float(t[0]))
        self.t0 = float(t[0]) + (starts[0] if align and starts else 0.0)
        self.time = t - self.t0
        self.starts = [float(t[0]) + s - self.t0 for s in starts]
        self.aligned = align and bool(starts)
        self.holes = holes_of(self.time, self.cycles)
        self.degraded = degraded_spans(run.messages.get("event", []), self.t0, float(self.time[0]),
                                       float(self.time[-1]))
        self.enabled = np.array([s["mode"] == "enabled" for s in run.samples], dtype=bool)

    def column(self, name: str) -> np.ndarray:
        """A field's values [SI], NaN where missing (a field this run's layout lacks: all NaN)."""
        if name not in self._columns:
            self._columns[name] = (np.asarray(self.run.column(name), dtype=float) if name in self.layout
                                   else np.full(len(self.run.samples), np.nan))
        return self._columns[name]

    def shown(self, name: str) -> np.ndarray:
        """A field's values in its display unit (deg, mm ...)."""
        return self.column(name) * self.layout[name].display[1] if name in self.layout else self.column(name)

    def broken(self, values: np.ndarray) -> np.ndarray:
        """A column (or the time) with a NaN in each hole: a drawn line stops there."""
        return np.insert(np.asarray(values, dtype=float), self.breaks, np.nan)

    @property
    def t(self) -> np.ndarray:
        return self.broken(self.time)


def _label(path: Path, run: recording.Run) -> str:
    return f"{path.stem} ({run.controller.get('name', '?')})"


def hole_notes(name: str, run: recording.Run) -> list[str]:
    """What the figures of a run with holes or degraded timing show, in words (none without)."""
    t = np.asarray(run.column("t"), dtype=float)
    return (hole_sentence(name, holes_of(t - t[0], np.asarray(run.column("cycle"), dtype=np.int64)))
            + degraded_sentence(name, degraded_spans(run.messages.get("event", []), float(t[0]), 0.0,
                                                     float(t[-1] - t[0]))))


def _distinct(runs: list[Drawn]) -> list[Drawn]:
    """The runs to draw: identical ones (every joint's position and commands) merged."""
    arrays = [np.array([r.column(f.name) for f in r.layout.fields if f.group == "command"
                        or f.quantity == "position"]).T for r in runs]
    merged = []
    for label, i in merge_identical([r.label for r in runs], arrays):
        runs[i].label = label
        merged.append(runs[i])
    return merged


def _colours() -> list:
    return plt.rcParams["axes.prop_cycle"].by_key()["color"] * 4


def _rows_figure(runs: list[Drawn], rows: list[tuple[str, str, object]], title: str, draw) -> plt.Figure | None:
    """A figure of one subplot per row (title, y label, what ``draw(ax, what, run, colour)``
    draws), time shared; None without rows."""
    if not rows:
        return None
    fig, axes = plt.subplots(len(rows), 1, figsize=(10, 3.2 * len(rows)), sharex=True, squeeze=False)
    colours = _colours()
    for ax, (name, ylabel, what) in zip(axes[:, 0], rows):
        for colour, run in zip(colours, runs):
            draw(ax, what, run, colour)
        shade_holes(ax, runs, colours)
        shade_degraded(ax, runs)
        for k, t in enumerate(sorted({t for run in runs for t in run.starts})):
            ax.axvline(t, **BOUNDARY, label="approach ends, path begins" if k == 0 else None)
        ax.set_title(name)
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel("time from the path's start [s]" if all(run.aligned for run in runs) else "time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def _per_joint(runs: list[Drawn], quantity: str) -> list[tuple[str, str, str]]:
    layout = runs[0].layout
    return [(f"{j} joint", fields.label(layout[f"{j}.{quantity}"], with_owner=False), j) for j in layout.owners()]


def _positions(ax, joint, run: Drawn, colour):
    for quantity, style, width in (("setpoint", "--", 1.0), ("position", "-", 1.4)):
        name = f"{joint}.{quantity}"
        if name in run.layout:
            ax.plot(run.t, run.broken(run.shown(name)), style, color=colour, lw=width,
                    label=f"{run.label} {fields.WORDS[quantity]}")


def _errors(ax, joint, run: Drawn, colour):
    if f"{joint}.error" in run.layout:
        ax.plot(run.t, run.broken(run.shown(f"{joint}.error")), color=colour, lw=1.2, label=run.label)


QUANTITY = {"kPa": "pressure", "V": "voltage", "N": "force", "N m": "torque", "K": "temperature", "deg": "angle",
            "mm": "length"}  # what a value in a unit is, for an axis that draws several fields


def _grouped(layout, keep, what: str = "") -> list[tuple[str, str, list[str]]]:
    """Rows of the fields ``keep`` picks, one per owner and display unit: (title, y label, names)."""
    rows: dict[tuple[str, str], list[str]] = {}
    for f in layout.fields:
        if keep(f):
            rows.setdefault((f.owner, fields.unit(f)), []).append(f.name)
    return [(f"{owner} joint" if owner else "rig",
             f"{what or (fields.name(layout[names[0]]) if len(names) == 1 else QUANTITY.get(unit, 'value'))} [{unit}]",
             names) for (owner, unit), names in rows.items()]


def _commands(ax, names, run: Drawn, colour):
    """Each command where the controller's was written (outside ``enabled`` the safe state
    was: none is drawn there), and its limits (``describe``'s command interfaces)."""
    limits = {(c["joint"], c["name"]): (c["low"], c["high"]) for c in run.run.describe.get("command_interfaces", [])}
    styles = iter(("-", "--", ":", "-."))
    for name in names:
        if name not in run.layout:
            continue
        f = run.layout[name]
        u = run.shown(name).copy()
        u[~run.enabled] = np.nan
        ax.plot(run.t, run.broken(u), next(styles, "-"), color=colour, lw=1.2,
                label=f"{run.label} {fields.name(f, with_owner=False)}")
        drawn = {line.get_label() for line in ax.get_lines()}
        for k, v in enumerate(limits.get((f.owner, f.quantity[2:]), ())):
            name = f"{f.quantity[2:]} limits"
            ax.axhline(v * f.display[1], **LIMIT, label=name if k == 0 and name not in drawn else None)


def _values(ax, names, run: Drawn, colour):
    """Measured values solid (then dotted), commanded ones dashed (then dash-dotted), each by its
    own name."""
    styles = {"commanded": iter(("--", "-.", (0, (5, 1, 1, 1)))), "measured": iter(("-", ":", (0, (1, 3))))}
    for name in names:
        if name in run.layout:
            f = run.layout[name]
            ax.plot(run.t, run.broken(run.shown(name)), next(styles.get(f.group, styles["measured"]), "-"),
                    color=colour, lw=1.2, label=f"{run.label} {fields.name(f, with_owner=False)}")


def _is_sensor(f) -> bool:
    """A joint's commanded pressures and further inputs, or a rig-level sensor."""
    return f.group == "commanded" or f.group == "measured" and f.quantity not in ("position", "velocity")


def _tip(runs: list[Drawn]) -> plt.Figure | None:
    fig, ax = plt.subplots(figsize=(7, 7))
    drawn = False
    for colour, run in zip(_colours(), runs):
        lengths = run.run.describe.get("arm", {}).get("link_lengths_mm", [])
        joints = run.layout.owners()
        if len(joints) < 2 or len(lengths) < 2 or any(run.layout[f"{j}.position"].unit != "rad" for j in joints[:2]):
            continue  # the arm's forward kinematics: two rotary joints
        a, b = joints[:2]
        for quantity, style, what in (("setpoint", "--", "reference"), ("position", "-", "tip")):
            q1, q2 = run.column(f"{a}.{quantity}"), run.column(f"{b}.{quantity}")
            x = lengths[0] * np.cos(q1) + lengths[1] * np.cos(q1 + q2)
            y = lengths[0] * np.sin(q1) + lengths[1] * np.sin(q1 + q2)
            ax.plot(run.broken(x), run.broken(y), style, color=colour, lw=1.0 if what == "reference" else 1.4,
                    label=f"{run.label} {what}")
            if what == "reference":
                start_and_direction(ax, x, y, run.time, run.starts, colour, run.label)
        if run.holes:  # (no time axis to shade: said in the legend, the lines broken)
            ax.plot([], [], " ", label=f"{run.label if len(runs) > 1 else ''} no data ({hole_words(run.holes)}): "
                                       "lines broken".strip())
        drawn = True
    if not drawn:
        plt.close(fig)
        return None
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="x [mm]", ylabel="y [mm]", title="tip path in the workspace (forward kinematics of the first two joints)")
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
    drawn = Drawn(label, run)
    names = list(messages[-1]["signals"])
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 2.4 * len(names)), sharex=True, squeeze=False)
    seq = np.array([m.get("seq", k) for k, m in enumerate(messages)], dtype=np.int64)
    lost = np.flatnonzero(np.diff(seq) > 1) + 1  # messages lost between these: the lines stop there
    t = np.insert(np.array([m["t"] for m in messages], dtype=float) - drawn.t0, lost, np.nan)
    for ax, name in zip(axes[:, 0], names):
        declared = sorted(units.get(name, {"-"}))
        unit, scale = DISPLAY.get(declared[0], (declared[0], 1.0)) if len(declared) == 1 else (" | ".join(declared), 1.0)
        for j, joint in enumerate(run.layout.owners()):
            values = [m["signals"][name][j] if name in m["signals"] else np.nan for m in messages]
            ax.plot(t, np.insert(np.array(values, dtype=float) * scale, lost, np.nan), lw=1.1, label=joint)
        shade_holes(ax, [drawn], ["0.45"])
        ax.set_ylabel(f"{name} [{unit}]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"controller internals: {label}")
    fig.tight_layout()
    return fig


def figures(runs: list[tuple[str, recording.Run]], align: bool | None = None) -> dict[str, plt.Figure | None]:
    """Every figure of the runs ((label, run) each), by name; None where there is nothing to
    draw. ``align``: times from each run's path start (default: when several runs are overlaid)."""
    align = len(runs) > 1 if align is None else align
    drawn = _distinct([Drawn(label, run, align) for label, run in runs])
    layout = drawn[0].layout

    def held(f) -> bool:  # a field some run has a number in (a force sensor the rig file has, but unplugged: none)
        return any(f.name in r.layout and np.isfinite(r.column(f.name)).any() for r in drawn)
    made = {"joints": _rows_figure(drawn, _per_joint(drawn, "position"), "joint positions and set-points", _positions),
            "errors": _rows_figure(drawn, _per_joint(drawn, "error"), "tracking error (set-point - position)", _errors),
            "output": _rows_figure(drawn, _grouped(layout, lambda f: f.group == "command", "command"),
                                   "controller output, each command (none drawn where the safe state was written)",
                                   _commands),
            "pressures": _rows_figure(drawn, _grouped(layout, lambda f: f.owner and _is_sensor(f) and held(f)),
                                      "chamber pressures, commanded (dashed) and measured (solid), "
                                      "and the joints' further inputs", _values),
            "rig": _rows_figure(drawn, _grouped(layout, lambda f: not f.owner and f.group == "measured" and held(f)),
                                "the rig's own sensors", _values),
            "tip": _tip(drawn)}
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
            say_cut(fig, notices)
        target = out / f"{stem}-{name}.png"
        fig.savefig(target, dpi=110)
        plt.close(fig)
        written.append(target)
    return written
