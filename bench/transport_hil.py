"""PID along a reference path over each real wire, beside the in-process simulator: the
acceptance figures of the transports issue (same error figures within a small margin).

    chrt -f 80 python -m bench.transport_hil [--path circle|translation] [--stale-ms MS] [--only serial,...]

The loop runs in this process on the real-time clock (run it under chrt for SCHED_FIFO), the
simulated rig in its peer process behind the wire at SCHED_FIFO 70 (the Modbus exchange
worker too). The in-process row runs on the virtual clock, as the controller comparison
does. The rig's own safety limits hold unless ``--stale-ms`` raises the stale-data limit (a loop
stall on a noisy machine ages a pipelined wire's sample by as much); Modbus RTU, whose
pymodbus client takes about 16 ms an exchange, always gets at least 50 ms. Rows say so.
"""
from __future__ import annotations

import argparse
import gc
import tempfile

from bench import scenarios as S
from bench import wires
from bench.common import header

RTU_STALE_S = 0.05


def track(name: str, wire: wires.Wire | None, path, approach_s: float, stale_s: float | None) -> str:
    peer = wires.start_peer(wire.peer, wire.ready, priority=70) if wire else None
    try:
        options = dict(wire.options) if wire else {}
        if wire and wire.backend == "modbus":
            options["worker_priority"] = 70
        stale = max(stale_s or 0.0, RTU_STALE_S if name == "modbus-rtu" else 0.0)
        safety = {"stale_after_s": stale} if stale else None
        gc.collect()
        gc.freeze()
        gc.disable()  # as the daemon runs its loop: no collector pauses
        loop = wires.wire_loop(wire.backend if wire else None, options, virtual=wire is None, safety=safety)
        loop.enable()  # and run straight away: a real-time loop left waiting trips as stalled
        S.approach(loop, path.sample(0.0)[0], approach_s)
        r = S.measure_path(loop, path)
        state = loop.state.value + (f" ({loop.supervisor.cause})" if loop.supervisor.cause else "")
        overruns = loop.stats.overruns_total
        loop.shutdown()
    finally:
        gc.enable()
        if peer is not None:
            wires.stop_peer(peer)
    label = name + (f" (stale limit {stale * 1e3:.0f} ms)" if stale else "")
    return (f"| {label} | {path.duration:.1f} s | {r.joint_max[0]:.2f} / {r.joint_max[1]:.2f} | "
            f"{r.joint_rms[0]:.2f} / {r.joint_rms[1]:.2f} | {r.tip_max:.2f} | {r.tip_rms:.2f} | {overruns} | {state} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--path", choices=("circle", "translation"), default="circle")
    ap.add_argument("--stale-ms", type=float, default=None, help="raise the rig's stale-data limit to this")
    ap.add_argument("--only", default=None, help="comma-separated rows to run, e.g. serial,can-udp")
    args = ap.parse_args()
    header(f"PID on the {args.path} over each wire")
    print("| wire | path duration | joint max (deg) bottom / middle | joint RMS (deg) | tip max (mm) | tip RMS (mm) "
          "| overruns | state after |")
    print("|---|---|---|---|---|---|---|---|")
    plan = S.make_loop("pid")  # planned beforehand: the real-time loops must not wait on it
    period = S.shortest_feasible(plan, args.path) if args.path == "circle" else 15.0
    path = S.make_path(plan, args.path, period)
    approach_s = S.approach_duration(plan, path.sample(0.0)[0]) * 1.2  # the arm may have sagged at start
    with tempfile.TemporaryDirectory(prefix="pneumad-hil-") as tmp:
        rows = {"in-process (virtual clock)": None, **wires.wires(tmp)}
        for name, wire in rows.items():
            if args.only and name not in args.only.split(","):
                continue
            print(track(name, wire, path, approach_s, args.stale_ms and args.stale_ms * 1e-3), flush=True)


if __name__ == "__main__":
    main()
