"""Reading recordings, whatever wrote them: MCAP (:mod:`daemon.recordings.mcap_log`, what pneumad
records today) and the msgpack ``.pnrec`` of earlier versions; export to CSV and loading into
numpy arrays for a notebook.

A ``.pnrec`` is a stream of msgpack objects: a header map (format, software version, the
daemon's describe() answer including the rig file's hash, the rig file's text, the active
controller, start time), then one ``[topic, message]`` pair per telemetry message.

A recording cut short (a killed recorder, a full disk, a copy that stopped) is read up to its
last complete chunk, never refused and never passed off as whole: :meth:`Run.cut_notice` says
it is cut and how much is missing, :func:`load` warns (:class:`CutRecording`) and flags its
result (``.cut``), ``pneumactl export`` and ``plot`` say it and exit 3 (docs/recordings.md).
"""
from __future__ import annotations

import csv
import warnings
from dataclasses import dataclass, field

import msgpack
import numpy as np

from daemon.recordings import mcap_log
from daemon.recordings.legacy import Converter, layout_of
from daemon.wire.cycle_layout import MODES, CycleLayout
from daemon.wire.telemetry_rows import CONTACT_FIELDS

FORMAT = "pneumad-recording/1"
MCAP_MAGIC = b"\x89MCAP"


@dataclass
class Run:
    """A recording's contents: the daemon's describe answer, the controller at the start,
    one flat state sample per cycle keyed by the cycle layout's field names (``layout``:
    ``{"cycle": 7, "t": 0.007, "middle.position": 0.52, ..., "mode": "enabled"}``, SI units,
    NaN for a number nobody wrote), the other topics' messages, whether the file was cut short
    (``truncated``: how; "" if not) and how long it was meant to run where it says (``plan``:
    ``planned_s``, ``planned_end_t``)."""

    describe: dict
    controller: dict
    samples: list[dict] = field(default_factory=list)
    messages: dict[str, list[dict]] = field(default_factory=dict)
    truncated: str = ""
    plan: dict[str, float] = field(default_factory=dict)
    layout: CycleLayout | None = None  # default: the describe's (layout_of)

    def __post_init__(self):
        if self.layout is None:
            self.layout = layout_of(self.describe)

    @property
    def joints(self) -> list[str]:
        return [j["name"] for j in self.describe["joints"]]

    def column(self, name: str) -> np.ndarray:
        """One field over the run, a float per cycle (NaN where nothing was written); ``mode``
        as the index into :data:`daemon.wire.cycle_layout.MODES`. KeyError for a field the
        layout has not."""
        if name not in self.layout:
            raise KeyError(f"{name!r} is not a field of this recording (its fields: {', '.join(self.layout.names)})")
        if name == "mode":
            return np.array([MODES.index(s["mode"]) if s["mode"] in MODES else np.nan for s in self.samples],
                            dtype=float)
        return np.array([s.get(name, np.nan) for s in self.samples], dtype=float)

    def cut_notice(self, name: str) -> str:
        """"" for a whole recording; for a cut one (``name``: its file's), that it is cut, how,
        what was read and how much is missing, as far as the file can tell: its planned length,
        or the end of the reference it holds, or else only that its end is missing."""
        if not self.truncated:
            return ""
        if not self.samples:
            return f"{name} is cut ({self.truncated}): no state sample in it"
        first, last = self.samples[0]["t"], self.samples[-1]["t"]
        text = f"{name} is cut ({self.truncated}): read {last - first:.1f} s from its first sample"
        end, of = self.plan.get("planned_end_t"), "planned"
        if end is None and "planned_s" in self.plan:
            end = first + self.plan["planned_s"]
        if end is None:
            ends = [e["t"] + e["duration_s"] for e in self.messages.get("event", [])
                    if e.get("kind") == "reference" and e.get("action") == "start" and e.get("duration_s")]
            end, of = (max(ends), "to the end of its reference (at least)") if ends else (None, of)
        if end is None:
            return text + "; what came after is missing (the file does not say how long it was to run)"
        if end <= last:
            return text + f" of the {end - first:.1f} s {of}: every planned sample is there"
        return text + f" of the {end - first:.1f} s {of}: about {end - last:.1f} s missing at its end"


class CutRecording(UserWarning):
    """A recording read up to a cut: what is returned is not the whole run."""


class Columns(dict):
    """:func:`load`'s columns by name; ``layout``: the state columns' fields (units, owners);
    ``cut``: "" for a whole recording, else what :meth:`Run.cut_notice` says (truthy: the run
    is not all there)."""

    cut: str = ""
    layout: CycleLayout | None = None


def open_run(path) -> Run:
    """Read a recording of either format (ValueError if it is neither)."""
    with open(path, "rb") as f:
        magic = f.read(len(MCAP_MAGIC))
    if magic == MCAP_MAGIC:
        found = mcap_log.read(path)
        messages = {t: m for t, m in found.messages.items() if t != "state"}
        return Run(found.describe, found.controller, found.messages["state"], messages, found.truncated, found.plan,
                   found.layout)
    return _read_pnrec(path)


def _read_pnrec(path) -> Run:
    with open(path, "rb") as f:
        unpacker = msgpack.Unpacker(f, raw=False)
        try:
            header = next(unpacker)
        except StopIteration:
            raise ValueError(f"{path}: empty file") from None
        except (ValueError, msgpack.UnpackException):
            header = None
        if not isinstance(header, dict) or header.get("format") != FORMAT:
            raise ValueError(f"{path}: not a pneumad recording (neither MCAP nor {FORMAT})")
        run = Run(header["describe"], header["controller"])
        convert = Converter(run.describe).columns  # its state messages' columns, as they were then
        try:
            for topic, message in unpacker:
                if topic == "state":
                    run.samples.extend(convert(message))
                else:
                    run.messages.setdefault(topic, []).append(message)
        except (ValueError, msgpack.UnpackException) as exc:
            run.truncated = f"{type(exc).__name__}: {exc}"
    return run


def export_csv(path, out, run: Run | None = None) -> int:
    """Write the state stream as CSV, one row per cycle, one column per field of the layout
    (headed ``name [unit]``, SI units; an empty cell where nothing was written); rows written (of
    a cut recording, every row up to the cut: its :meth:`Run.cut_notice` says so). ``run``: the
    recording at ``path`` opened already."""
    run = run if run is not None else open_run(path)
    names = run.layout.names
    with open(out, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([f"{f.name} [{f.unit}]" for f in run.layout.fields])
        for s in run.samples:
            w.writerow(["" if (v := s.get(name)) is None or v != v else v for name in names])
    return len(run.samples)


def load(path) -> Columns:
    """The state stream as numpy columns, one per field of the cycle layout (``t``, ``cycle``,
    ``middle.position`` [rad] ..., SI units, NaN where nothing was written; ``cycle`` integers,
    ``mode`` the state's names; ``.layout`` says each one's unit), and the controller's internal
    signals as ``internals.t`` and ``internals.<signal>.<joint>`` where recorded, and the array
    sensor's estimates as ``contact.frame_t``, ``contact.<field>`` (NaN where nothing touched):
    for a notebook. ``pandas.DataFrame(load(path))`` works for the state columns (same length).
    A cut recording gives what it holds, with a :class:`CutRecording` warning and ``.cut`` saying
    how much is missing."""
    run = open_run(path)
    out = Columns()
    out.layout = run.layout
    out.cut = run.cut_notice(str(path))
    if out.cut:
        warnings.warn(out.cut, CutRecording, stacklevel=2)
    for name in run.layout.names:
        if name == "cycle":
            out[name] = np.array([s["cycle"] for s in run.samples], dtype=np.int64)
        elif name == "mode":
            out[name] = np.array([s["mode"] for s in run.samples], dtype=str)
        else:
            out[name] = run.column(name)
    internals = run.messages.get("internals", [])
    if internals:
        out["internals.t"] = np.array([m["t"] for m in internals], dtype=float)
        for signal in internals[-1]["signals"]:
            for j, name in enumerate(run.joints):
                out[f"internals.{signal}.{name}"] = np.array(
                    [m["signals"].get(signal, [np.nan] * len(run.joints))[j] for m in internals], dtype=float)
    contact = run.messages.get("contact", [])
    if contact:
        out["contact.frame_t"] = np.array([m["frame_t"] for m in contact], dtype=float)
        for key in CONTACT_FIELDS:
            # (.get: a field newer than the recording, e.g. track_frames, reads as NaN)
            out[f"contact.{key}"] = np.array([m["contact"].get(key, np.nan) if m["contact"] else np.nan
                                              for m in contact], dtype=float)
    return out
