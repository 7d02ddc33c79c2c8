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
from daemon.wire.telemetry_rows import CONTACT_FIELDS

FORMAT = "pneumad-recording/1"
MCAP_MAGIC = b"\x89MCAP"


@dataclass
class Run:
    """A recording's contents: the daemon's describe answer, the controller at the start,
    one state sample per cycle (:func:`daemon.recordings.mcap_log.state_samples`'s shape), the other
    topics' messages, whether the file was cut short (``truncated``: how; "" if not) and how long
    it was meant to run where it says (``plan``: ``planned_s``, ``planned_end_t``)."""

    describe: dict
    controller: dict
    samples: list[dict] = field(default_factory=list)
    messages: dict[str, list[dict]] = field(default_factory=dict)
    truncated: str = ""
    plan: dict[str, float] = field(default_factory=dict)

    @property
    def joints(self) -> list[str]:
        return [j["name"] for j in self.describe["joints"]]

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
    """:func:`load`'s columns by name; ``cut``: "" for a whole recording, else what
    :meth:`Run.cut_notice` says (truthy: the run is not all there)."""

    cut: str = ""


def open_run(path) -> Run:
    """Read a recording of either format (ValueError if it is neither)."""
    with open(path, "rb") as f:
        magic = f.read(len(MCAP_MAGIC))
    if magic == MCAP_MAGIC:
        found = mcap_log.read(path)
        messages = {t: m for t, m in found.messages.items() if t != "state"}
        return Run(found.describe, found.controller, found.messages["state"], messages, found.truncated, found.plan)
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
        outputs = [o[0] for o in run.describe["transport"]["outputs"]]
        try:
            for topic, message in unpacker:
                if topic == "state":
                    run.samples.extend(mcap_log.state_samples(message, run.joints, outputs, mcap_log.command_fields(run.describe)))
                else:
                    run.messages.setdefault(topic, []).append(message)
        except (ValueError, msgpack.UnpackException) as exc:
            run.truncated = f"{type(exc).__name__}: {exc}"
    return run


def export_csv(path, out, run: Run | None = None) -> int:
    """Write the state stream as CSV, one row per cycle, columns named with units; rows written
    (of a cut recording, every row up to the cut: its :meth:`Run.cut_notice` says so). ``run``:
    the recording at ``path`` opened already."""
    run = run if run is not None else open_run(path)
    outputs = [o[0] for o in run.describe["transport"]["outputs"]]
    columns = (["cycle", "t"] + [f"{n}.{f}" for f in mcap_log.PER_JOINT for n in run.joints]
               + [f"volts.{o}" for o in outputs] + ["force_n", "mode"])
    with open(out, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for s in run.samples:
            w.writerow([s["cycle"], s["t"]] + [s["joints"][n][f] for f in mcap_log.PER_JOINT for n in run.joints]
                       + [s["out_volts"].get(o) for o in outputs] + [s["force_n"], s["mode"]])
    return len(run.samples)


def load(path) -> Columns:
    """The state stream as numpy columns named with their units (``t``, ``cycle``,
    ``middle.angle_rad`` ...), and the controller's internal signals as
    ``internals.t`` and ``internals.<signal>.<joint>`` where recorded, and the array sensor's
    estimates as ``contact.frame_t``, ``contact.<field>`` (NaN where nothing touched): for a notebook.
    ``pandas.DataFrame(load(path))`` works for the state columns (same length). A cut recording
    gives what it holds, with a :class:`CutRecording` warning and ``.cut`` saying how much is missing."""
    run = open_run(path)
    out = Columns()
    out.cut = run.cut_notice(str(path))
    if out.cut:
        warnings.warn(out.cut, CutRecording, stacklevel=2)
    out["t"] = np.array([s["t"] for s in run.samples], dtype=float)
    out["cycle"] = np.array([s["cycle"] for s in run.samples], dtype=np.int64)
    out["force_n"] = np.array([s["force_n"] for s in run.samples], dtype=float)
    for name in run.joints:
        for key in mcap_log.PER_JOINT:
            out[f"{name}.{key}"] = np.array([s["joints"][name][key] for s in run.samples], dtype=float)
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
