"""Reading recordings, whatever wrote them: MCAP (:mod:`daemon.recordings.mcap_log`, what pneumad
records today) and the msgpack ``.pnrec`` of earlier versions; export to CSV and loading into
numpy arrays for a notebook.

A ``.pnrec`` is a stream of msgpack objects: a header map (format, software version, the
daemon's describe() answer including the rig file's hash, the rig file's text, the active
controller, start time), then one ``[topic, message]`` pair per telemetry message.
"""
from __future__ import annotations

import csv
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
    topics' messages, and whether the file was cut short."""

    describe: dict
    controller: dict
    samples: list[dict] = field(default_factory=list)
    messages: dict[str, list[dict]] = field(default_factory=dict)
    truncated: str = ""

    @property
    def joints(self) -> list[str]:
        return [j["name"] for j in self.describe["joints"]]


def open_run(path) -> Run:
    """Read a recording of either format (ValueError if it is neither)."""
    with open(path, "rb") as f:
        magic = f.read(len(MCAP_MAGIC))
    if magic == MCAP_MAGIC:
        found = mcap_log.read(path)
        messages = {t: m for t, m in found.messages.items() if t != "state"}
        return Run(found.describe, found.controller, found.messages["state"], messages, found.truncated)
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


def export_csv(path, out) -> int:
    """Write the state stream as CSV, one row per cycle, columns named with units; rows written."""
    run = open_run(path)
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


def load(path) -> dict[str, np.ndarray]:
    """The state stream as numpy columns named with their units (``t``, ``cycle``,
    ``middle.angle_rad`` ...), and the controller's internal signals as
    ``internals.t`` and ``internals.<signal>.<joint>`` where recorded, and the array sensor's
    estimates as ``contact.frame_t``, ``contact.<field>`` (NaN where nothing touched): for a notebook.
    ``pandas.DataFrame(load(path))`` works for the state columns (same length)."""
    run = open_run(path)
    out = {"t": np.array([s["t"] for s in run.samples], dtype=float),
           "cycle": np.array([s["cycle"] for s in run.samples], dtype=np.int64),
           "force_n": np.array([s["force_n"] for s in run.samples], dtype=float)}
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
