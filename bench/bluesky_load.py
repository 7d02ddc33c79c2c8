"""The loop while a Bluesky RunEngine drives it, against the same daemon left alone.

Usage: python -m bench.bluesky_load [--seconds 30] [--priority 80]

Starts a real ``pneumad`` (simulated rig, SCHED_FIFO at --priority where permitted, one stats
window per phase), then: a phase of --seconds with the arm enabled and holding, no client but
the stats subscriber; a phase of the same length with a RunEngine (TiledWriter into a local
Tiled server) running step-response plans back to back on the rig device, each recorded by
the daemon and turned into HDF5. Prints each phase's loop figures: cycles, overruns, wake-up
latency and compute p50/p99/max, and the plans run.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import msgpack

from bench.common import header, spawn_daemon, stats_subscriber
from daemon.client.client import Client
from daemon.testing.daemons import STOP_WAIT_S


def window(sub, seconds: float) -> dict:
    """The next stats window's summary (the daemon closes one every --stats-period)."""
    if not sub.poll(int((seconds + 10) * 1e3)):
        raise SystemExit("no stats window from the daemon")
    return msgpack.unpackb(sub.recv_multipart()[1], raw=False)


def line(name: str, stats: dict, plans: int | None = None) -> None:
    lat, comp = stats["latency_us"], stats["compute_us"]["compute"]
    ran = f", {plans} plans run" if plans is not None else ""
    print(f"{name:30s} cycles {stats['cycles']:6d}, overruns {stats['overruns']:4d}; latency p50/p99/max "
          f"{lat['p50']:.0f}/{lat['p99']:.0f}/{lat['max']:.0f} us; compute p50/p99/max "
          f"{comp['p50']:.0f}/{comp['p99']:.0f}/{comp['max']:.0f} us{ran}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--priority", type=int, default=80)
    args = ap.parse_args()
    from bluesky import RunEngine
    from bluesky.callbacks.tiled_writer import TiledWriter
    from tiled.client import from_uri
    from tiled.server import SimpleTiledServer

    from daemon.client.bluesky import plans
    from daemon.client.bluesky.device import PneumadRig

    header("the loop with a Bluesky RunEngine driving it (step responses, daemon-side records to HDF5, Tiled)")
    daemon, eps = spawn_daemon("--rt-priority", str(args.priority), "--stats-period", str(args.seconds))
    tmp = Path(tempfile.mkdtemp(prefix="pneumad-bench-bluesky-"))
    (tmp / "h5").mkdir()
    server = SimpleTiledServer(directory=tmp / "tiled", readable_storage=[tmp / "h5"])
    try:
        with Client(**eps, timeout=5.0) as client:
            client.ping()
            client.acquire_lease()
            client.enable()
            client.release_lease()  # the rig file's unleased action is hold: the arm stays enabled
        sub = stats_subscriber(eps)
        window(sub, args.seconds)  # the window the start-up fell in
        line("holding, no client", window(sub, args.seconds))
        engine = RunEngine({})
        engine.subscribe(TiledWriter(from_uri(server.uri)))
        rig = PneumadRig.connect_to("arm", hdf5_directory=str(tmp / "h5"), **eps)
        end, runs, step = time.monotonic() + args.seconds, 0, 2.0
        while time.monotonic() < end:
            engine(plans.step_response(rig, "bottom", step))
            runs, step = runs + 1, -step
        rig.close()
        line("RunEngine driving it", window(sub, args.seconds), runs)
    finally:
        server.close()
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


if __name__ == "__main__":
    main()
