"""The loop's timing with the array sensor's process beside it, against the same daemon without.

    python -m bench.contact_loop [--seconds 20] [--rate-hz 4000]

Runs a real ``pneumad`` (built-in simulated rig, SCHED_FIFO where permitted) twice for
``--seconds``: without a ``[contact_sensor]``, then with one at ``--rate-hz``; each run's
loop statistics are one stats window over the whole run. Prints the loop's wake-up latency,
compute time and overruns for both, and the sensor process's counters (frames estimated,
passed over) from its last ``contact`` message: what the estimator beside the loop costs
the loop, measured in one sitting.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from importlib import resources
from pathlib import Path

import msgpack
import zmq

from bench.common import header, secure, spawn_daemon, stats_subscriber
from daemon.client.client import Client
from daemon.testing.daemons import STOP_WAIT_S


def run(rig_text: str, seconds: float) -> tuple[dict, dict | None]:
    """(the stats window over the run, the last contact message or None)."""
    rig = Path(tempfile.mkdtemp(prefix="pneumad-contact-")) / "rig.toml"
    rig.write_text(rig_text)
    daemon, eps = spawn_daemon("--config", str(rig), "--stats-period", str(seconds))
    try:
        Client(**eps, timeout=30.0).ping()
        stats = stats_subscriber(eps)
        contact = secure(zmq.Context.instance().socket(zmq.SUB))
        contact.setsockopt(zmq.SUBSCRIBE, b"contact")
        contact.connect(eps["telemetry"])
        window, last = None, None
        deadline = time.monotonic() + 2.5 * seconds + 10.0
        while window is None and time.monotonic() < deadline:
            if stats.poll(100):
                message = msgpack.unpackb(stats.recv_multipart()[1], raw=False)
                if message["cycles"] > 0.9 * seconds * 1000:  # a whole window, not the first partial one
                    window = message
            while contact.poll(0):
                last = msgpack.unpackb(contact.recv_multipart()[1], raw=False)
        stats.close()
        contact.close()
        if window is None:
            raise SystemExit("no whole stats window from the daemon")
        return window, last
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.contact_loop", description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rate-hz", type=float, default=4000.0)
    args = ap.parse_args(argv)
    header(f"the loop with and without the array sensor's process beside it ({args.rate_hz:g} Hz frames)")
    base = resources.files("hal").joinpath("sim_2joint.toml").read_text()
    sensor = f"\n[contact_sensor]\nrate_hz = {args.rate_hz}\nsim_impact_every_s = 1.0\n"
    rows = [("without the sensor", *run(base, args.seconds)), ("with the sensor", *run(base + sensor, args.seconds))]
    print("\n| run | cycles | overruns | latency p99 / max [us] | compute p99 / max [us] |")
    print("|---|---|---|---|---|")
    for name, window, _ in rows:
        lat, comp = window["latency_us"], window["compute_us"]["compute"]
        print(f"| {name} | {window['cycles']} | {window['overruns']} | {lat['p99']:.0f} / {lat['max']:.0f} | "
              f"{comp['p99']:.0f} / {comp['max']:.0f} |")
    last = rows[1][2]
    if last is not None:
        print(f"\nsensor process: {last['frames']} frames estimated, {last['late_frames']} passed over "
              f"({last['late_frames'] / max(last['frames'] + last['late_frames'], 1):.1%}), {last['bad_frames']} bad; "
              f"estimate age at the last message {last['age_s'] * 1e3:.2f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
