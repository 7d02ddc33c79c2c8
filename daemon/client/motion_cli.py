"""pneumactl's motion commands (set, path, waypoints, steps, excite): their options, and each
sent with the lease and, with ``--wait``, followed to its end; the one-shot lease the other
commands take too."""
from __future__ import annotations

import sys

from daemon.wire.catalog import COMMANDS

from daemon.client.client import Client, read_waypoints

MOTION = ("set", "path", "waypoints", "steps", "excite")  # the commands motion() sends
NOT_ENDED = 4  # exit status: --wait saw the arm leave enabled before its reference ended
ONE_SHOT_LEASE_S = 10.0  # a one-shot command's lease [s], renewed every second until it is handed back


def with_lease(client: Client, fn):
    """One-shot commands take the lease, act, and hand it back (the arm keeps its state; if
    it stays enabled, the daemon's note on what becomes of it is printed, the first time in
    that enabled period only). The lease is
    renewed while the command runs: a command whose work is done beside the loop (a
    controller built at nice 10, a plan) can take longer than any fixed lease on a busy PC,
    and a lapsed lease trips an enabled arm. It is asked for ``ONE_SHOT_LEASE_S``, not the
    rig's 2 s: on a loaded PC this process can be held longer than that between renewals."""
    client.acquire_lease(ONE_SHOT_LEASE_S)
    client.keep_lease(every_s=1.0)
    try:
        return fn()
    finally:
        released = client.release_lease()
        if released and "unleased" in released and released["unleased"]["first"]:
            print(f"note: {released['unleased']['note']}", file=sys.stderr)


def option_help(cmd: str, arg: str) -> str:
    """An option's help: its argument's line in the command catalog (bounds, unit, default)."""
    return COMMANDS[cmd].arg(arg).help()


def add_parsers(sub) -> None:
    """The motion commands' subparsers, each with --record and --wait."""
    s = sub.add_parser("set", help=COMMANDS["set"].doc)
    motion = [s]
    s.add_argument("values", type=float, nargs="+", help="one position per joint: deg (rotary), mm (linear)")
    s.add_argument("--xy", action="store_true", help="values are x y in mm")
    s.add_argument("--duration", type=float, default=0.0, help=option_help("set", "duration_s"))
    s.add_argument("--stiffness", type=float, default=None, metavar="NM_PER_DEG", help=option_help("set", "stiffness_nm_deg"))
    pa = sub.add_parser("path", help=COMMANDS["path"].doc)
    motion.append(pa)
    pa.add_argument("name", choices=["translation", "circle"])
    pa.add_argument("--duration", type=float, default=None, help=option_help("path", "duration_s"))
    pa.add_argument("--approach", type=float, default=None, help=option_help("path", "approach_s"))
    wp = sub.add_parser("waypoints", help="run a path through waypoints from a CSV file")
    motion.append(wp)
    wp.add_argument("file", help="header duration_s,x_mm,y_mm or duration_s then each joint once by name and "
                                "unit, any order: <joint>_deg (rotary), <joint>_mm (linear)")
    wp.add_argument("--approach", type=float, default=None, help=option_help("waypoints", "approach_s"))
    st = sub.add_parser("steps", help="a step sequence: LEVEL ... with LEVEL = comma-separated joint positions "
                                             "[deg rotary, mm linear]")
    motion.append(st)
    st.add_argument("levels", nargs="+")
    st.add_argument("--hold", default="5", help="hold time per level [s], one value or one per level (comma list)")
    ex = sub.add_parser("excite", help="identification signal on one joint's reference (or, --input, its V_MV)")
    motion.append(ex)
    ex.add_argument("signal", choices=["chirp", "prbs", "multisine"])
    ex.add_argument("joint")
    ex.add_argument("--amplitude", type=float, default=1.0, help="[deg], or [V] with --input (default 1)")
    ex.add_argument("--input", action="store_true",
                    help="open loop: the signal on the joint's V_MV about the present set-point, the others held")
    for flag, arg in (("--settle", "settle_s"), ("--band", "band_deg"), ("--components", "components"),
                      ("--period", "period_s"), ("--f0", "f0_hz"), ("--f1", "f1_hz"), ("--duration", "duration_s"),
                      ("--order", "order"), ("--bit", "bit_s"), ("--periods", "periods")):
        spec = COMMANDS["excite"].arg(arg)
        ex.add_argument(flag, type=int if spec.kind == "integer" else float,
                        default=1 if arg == "periods" else spec.default, help=spec.help())
    for m in motion:
        m.add_argument("--record", action="store_true",
                       help="the daemon records it, start to end plus 3 s, in its recording directory")
        m.add_argument("--wait", action="store_true", help="show its progress and return when it has ended (exit "
                       f"{NOT_ENDED} if the arm left enabled first: a trip, an e-stop, a disable)")


def motion(client: Client, args):
    """A motion command (with the lease); ``--wait`` follows it to its end (and its recording)."""
    w, record = args.what, args.record
    if w == "set":
        kw = {"xy_mm": args.values} if args.xy else {"positions": args.values}
        send = lambda: client.set(duration_s=args.duration, record=record, stiffness_nm_deg=args.stiffness,  # noqa: E731
                                  **kw)
    elif w == "path":
        send = lambda: client.path(args.name, args.duration, args.approach, record=record)  # noqa: E731
    elif w == "waypoints":
        try:
            spec = read_waypoints(args.file, client.joint_units())
        except (OSError, ValueError) as exc:
            raise SystemExit(str(exc)) from None
        send = lambda: client.waypoints(**spec, approach_s=args.approach, record=record)  # noqa: E731
    elif w == "steps":
        levels = [[float(v) for v in level.split(",")] for level in args.levels]
        holds = [float(v) for v in args.hold.split(",")]
        holds = holds * len(levels) if len(holds) == 1 else holds
        send = lambda: client.steps(levels, holds, record=record, key="positions")  # noqa: E731
    else:
        settings = {"chirp": {"f0_hz": args.f0, "f1_hz": args.f1, "duration_s": args.duration},
                    "prbs": {"order": args.order, "bit_s": args.bit, "periods": args.periods},
                    "multisine": {"f0_hz": args.f0, "f1_hz": args.f1, "components": args.components,
                                  "period_s": args.period, "periods": args.periods}}[args.signal]
        if args.input:
            settings.update(settle_s=args.settle, band_deg=args.band)
        excite = client.excite_input if args.input else client.excite
        send = lambda: excite(args.signal, args.joint, args.amplitude, record=record, **settings)  # noqa: E731
    result = with_lease(client, send)
    if "stretched_from_s" in result:
        print(f"note: the {result['path']} path's {result['stretched_from_s']:g} s is beyond this rig; it runs in the "
              f"shortest it can follow, {result['duration_s']:g} s (--duration sets it)", file=sys.stderr)
    if not args.wait:
        return result
    from daemon.client.progress import follow  # rich: only for the progress display
    return {**result, **follow(client, result.get("total_s", result.get("duration_s", 0.0)), result.get("recording"))}
