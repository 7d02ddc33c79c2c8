"""A step experiment from a script or a notebook: take the lease, enable, step the bottom
joint by 5 deg, record it, and plot it; the recording then loads into numpy arrays.

    python examples/step_experiment.py [--out step-run] [--step-deg 5] [--seconds 8]

Needs a running daemon (``pneumad``; the simulated rig by default). Writes OUT.mcap and the
figures OUT-joints.png, OUT-errors.png ... next to it, and prints the step's overshoot.
"""
from __future__ import annotations

import argparse
import math
import threading
from pathlib import Path

from daemon.recordings import mcap_log, reading as recording

from daemon.client import plots
from daemon.client import Client
from daemon.wire.protocol import DEFAULT_COMMAND, DEFAULT_CONTROL, DEFAULT_TELEMETRY


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="step-run")
    ap.add_argument("--step-deg", type=float, default=5.0)
    ap.add_argument("--seconds", type=float, default=8.0)
    for name, default in (("command", DEFAULT_COMMAND), ("control", DEFAULT_CONTROL), ("telemetry", DEFAULT_TELEMETRY)):
        ap.add_argument(f"--{name}", default=default, help=f"the daemon's {name} endpoint (default {default})")
    args = ap.parse_args()
    endpoints = {"command": args.command, "control": args.control, "telemetry": args.telemetry}
    path = Path(args.out).with_suffix(".mcap")
    with Client(**endpoints, timeout=5.0) as c:
        c.acquire_lease()
        c.keep_lease()
        if c.status()["state"] != "enabled":  # a daemon left enabled (e.g. by the README's snippet) is used as it is
            c.enable()
        layout, here = c.layout(), c.sample()  # where the arm is: the cycle record's latest row
        joints = layout.owners()
        target = [math.degrees(here[f"{j}.position"]) for j in joints]
        target[0] += args.step_deg
        with Client(**endpoints, timeout=5.0) as listener:  # its own client: a client's sockets serve one thread
            started = threading.Event()
            recorder = threading.Thread(target=mcap_log.record, args=(listener, path, args.seconds),
                                        kwargs={"started": started})
            recorder.start()  # records while the step runs
            started.wait(10.0)  # once the daemon publishes to the recording
            threading.Event().wait(0.5)  # and half a second of rest before the step
            c.set(angles_deg=target)  # a step: no duration
            recorder.join()
        c.disable()
        c.release_lease()
    data = recording.load(path)  # numpy columns, one per field of the cycle record (SI: rad)
    name = joints[0]
    angle = [math.degrees(a) for a in data[f"{name}.position"]]
    first, peak = angle[0], max(angle) if args.step_deg > 0 else min(angle)
    print(f"{name}: step {args.step_deg:g} deg, overshoot {100 * (abs(peak - first) / abs(args.step_deg) - 1):.1f} %")
    for figure in plots.plot_runs([path], path.parent):
        print(figure)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
