"""Telemetry recordings: a self-describing file, and its export to CSV.

A recording is a stream of msgpack objects: first a header map (format, software version,
the daemon's describe() answer including the rig file's hash, the rig file's text, the
active controller and its parameters, start time), then one ``[topic, message]`` pair per
telemetry message as received. Any msgpack reader can read it.
"""
from __future__ import annotations

import csv
import time
from collections.abc import Iterator

import msgpack

FORMAT = "pneumad-recording/1"


def write_header(f, describe: dict, controller: dict, rig_source: str) -> None:
    f.write(msgpack.packb({"format": FORMAT, "software": describe.get("version"), "started": time.time(),
                           "describe": describe, "rig_source": rig_source, "controller": controller}))


def write_message(f, topic: str, message: dict) -> None:
    f.write(msgpack.packb([topic, message]))


def read(path) -> tuple[dict, Iterator[tuple[str, dict]]]:
    """The header and an iterator over (topic, message)."""
    f = open(path, "rb")
    unpacker = msgpack.Unpacker(f, raw=False)
    try:
        header = next(unpacker)
    except StopIteration:
        f.close()
        raise ValueError(f"{path}: empty file") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        f.close()
        raise ValueError(f"{path}: not a pneumad recording (format {header.get('format') if isinstance(header, dict) else '?'})")

    def messages():
        with f:
            for item in unpacker:
                yield item[0], item[1]

    return header, messages()


def export_csv(path, out) -> int:
    """Write the state stream as CSV, one row per cycle, columns named with units; rows written."""
    header, messages = read(path)
    names = [j["name"] for j in header["describe"]["joints"]]
    per_joint = ["angle_rad", "velocity_rad_s", "setpoint_rad", "error_rad", "u_volts", "p_head_pa", "p_rod_pa"]
    outputs = [o[0] for o in header["describe"]["transport"]["outputs"]]
    columns = (["cycle", "t"] + [f"{n}.{f}" for f in per_joint for n in names]
               + [f"volts.{o}" for o in outputs] + ["force_n", "mode"])
    rows = 0
    with open(out, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for topic, m in messages:
            if topic != "state":
                continue
            for i in range(len(m["cycle"])):
                row = [m["cycle"][i], m["t"][i]]
                for f in per_joint:
                    row.extend(m[f][i])
                row.extend(m["out_volts"][i])
                row.extend([m["force_n"][i], m["mode"][i]])
                w.writerow(row)
                rows += 1
    return rows
