"""What ``pneumactl plot``'s figures mark so that nothing misleads (:mod:`daemon.client.plots`):
holes in the data (cycles a slow client lost) as gaps and shaded spans, spans where the loop's
timing was degraded (its ``timing`` events) hatched, runs a figure cannot
tell apart merged and named together, where a path begins after its approach, the tip path's
start and direction, and a cut recording's notice."""
from __future__ import annotations

import textwrap

import numpy as np

BOUNDARY = dict(color="0.35", ls=":", lw=1.2)  # the approach/path boundary
HOLE = dict(alpha=0.18, lw=0)  # a span with no data
DEGRADED = dict(facecolor="none", edgecolor="tab:red", hatch="///", alpha=0.35, lw=0)  # the loop's timing degraded
CUT = dict(color="firebrick", fontsize=8.5, ha="center", va="bottom")  # the note on a cut recording's figures


def holes_of(t: np.ndarray, cycles: np.ndarray) -> list[tuple[float, float, int]]:
    """Where a state stream has no data: two samples in a row whose cycles are not (telemetry
    lost on its way, e.g. to a slow client), as (the sample before [s], the sample after [s],
    cycles missing), ``t`` the samples' times [s]."""
    return [(float(t[i]), float(t[i + 1]), int(cycles[i + 1] - cycles[i] - 1))
            for i in np.flatnonzero(np.diff(cycles) > 1)]


def hole_words(found: list[tuple[float, float, int]]) -> str:
    total = sum(b - a for a, b, _ in found)
    return f"{len(found)} hole{'s' if len(found) > 1 else ''}, {total:.2f} s"


def hole_sentence(name: str, found: list[tuple[float, float, int]]) -> list[str]:
    """What the figures of a run with holes show, in words (none without holes)."""
    if not found:
        return []
    return [f"{name}: no data in {hole_words(found)} in all ({_each(found, 2)}; {sum(n for *_, n in found)} cycles missing): "
            f"drawn as gaps, shaded"]


def _each(spans: list[tuple], digits: int) -> str:
    """Spans (from, to [s], ...) in words, the first ten: "0.50 s at 3.20 s, ..."."""
    return (", ".join(f"{b - a:.{digits}f} s at {a:.{digits}f} s" for a, b, *_ in spans[:10])
            + (" ..." if len(spans) > 10 else ""))


def shade_holes(ax, runs, colours) -> None:
    """Each run's holes as shaded spans, one legend entry per run ("no data"); ``runs`` are
    :class:`daemon.client.plots.Drawn`."""
    for colour, run in zip(colours, runs):
        found = run.holes
        for k, (a, b, _) in enumerate(found):
            name = f"no data ({hole_words(found)})" if len(runs) == 1 else f"{run.label}: no data ({hole_words(found)})"
            ax.axvspan(a, b, color="0.45" if len(runs) == 1 else colour, **HOLE, label=name if k == 0 else None)


def degraded_spans(events: list[dict], t0: float, first: float, last: float) -> list[tuple[float, float, str]]:
    """Where the loop's timing was degraded in a run (docs/protocol.md, "The loop's timing"), as
    (from, to [s from ``t0``], cause), erring wide: a ``timing`` event that says degraded opens a
    span at the start of the window it judged (``since_t``), and one that says it is back within
    the limits closes it at its own time (``t``: the loop may have recovered anywhere in the
    window it judged); a span the run begins or ends inside runs from its ``first`` or to its
    ``last`` sample [s from ``t0``]."""
    spans, opened = [], None
    for e in events:
        if e.get("kind") != "timing":
            continue
        if e.get("degraded"):
            opened = opened or (max(float(e.get("since_t", e["t"])) - t0, first), e.get("cause", ""))
        else:
            start, cause = opened or (first, "degraded when the recording began")
            spans.append((start, min(max(float(e["t"]) - t0, start), last), cause))
            opened = None
    if opened is not None:
        spans.append((opened[0], last, opened[1]))
    return spans


def degraded_sentence(name: str, spans: list[tuple[float, float, str]]) -> list[str]:
    """What the figures of a run with degraded timing show, in words (none without)."""
    if not spans:
        return []
    return [f"{name}: the loop's timing was degraded in {sum(b - a for a, b, _ in spans):.1f} s ({_each(spans, 1)}; "
            f"{spans[0][2]}): hatched; what it ran there was not at the loop's rate"]


def shade_degraded(ax, runs) -> None:
    """Each run's degraded spans hatched, one legend entry ("loop timing degraded")."""
    k = 0
    for run in runs:
        for a, b, _ in run.degraded:
            ax.axvspan(a, b, **DEGRADED, label="loop timing degraded" if k == 0 else None)
            k += 1


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


def path_starts(describe: dict, events: list[dict], t0: float) -> list[float]:
    """Where each path began after its approach [s from ``t0``]: its ``reference`` event
    ``settled`` (the daemon holds the path's start until the arm has settled there), or, in
    recordings made before the daemon waited, the start event's time plus its ``approach_s``
    (recordings before that: none)."""
    period = describe.get("period_s", 0.001)
    events = [e for e in events if e.get("kind") == "reference"]
    settled = {e.get("generation"): e["t"] for e in events if e.get("action") == "settled"}
    return [settled.get(e.get("generation"), e["t"] + period + e["approach_s"]) - t0 for e in events
            if e.get("action") == "start" and e.get("approach_s") is not None]


def start_and_direction(ax, x, y, t, starts: list[float], colour, label: str) -> None:
    """The reference's start (a circle), where the path begins after its approach (a square),
    and arrows along it, so a reader sees where it starts and which way it runs."""
    ax.plot(x[:1], y[:1], "o", color=colour, ms=7, mfc="none", mew=1.6, label=f"{label} start")
    for k, ts in enumerate(starts):
        i = min(int(np.searchsorted(t, ts)), len(x) - 1)
        ax.plot(x[i:i + 1], y[i:i + 1], "s", color=colour, ms=7, mfc="none", mew=1.6,
                label=f"{label} path begins (approach ends)" if k == 0 else None)
    step = np.hypot(np.diff(x), np.diff(y))
    along = np.concatenate([[0.0], np.nancumsum(step)])
    if along[-1] <= 0:
        return
    for f in (0.15, 0.4, 0.65, 0.9):  # arrows at fractions of the length drawn
        i = min(int(np.searchsorted(along, f * along[-1])), len(x) - 2)
        j = min(i + max(len(x) // 200, 1), len(x) - 1)
        if np.isfinite([x[i], y[i], x[j], y[j]]).all() and (x[j], y[j]) != (x[i], y[i]):
            ax.annotate("", xy=(x[j], y[j]), xytext=(x[i], y[i]),
                        arrowprops=dict(arrowstyle="-|>", color=colour, lw=1.2, mutation_scale=16))


def say_cut(fig, notices: list[str]) -> None:
    """A cut recording's notice at the foot of a figure, room made for it."""
    width, height = fig.get_size_inches()
    lines = [line for notice in notices for line in textwrap.wrap(notice, int(13 * width))]
    room = (0.16 * len(lines) + 0.1) / height  # [fraction of the figure]
    fig.subplots_adjust(bottom=fig.subplotpars.bottom + room)
    fig.text(0.5, 0.06 / height, "\n".join(lines), **CUT)
