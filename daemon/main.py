"""``pneumad``: the daemon (``run``, the default), the latency qualification, the dead-man
command that writes the safe state (``safe-state``, for systemd's ExecStopPost), and the
daemon's CURVE keys (``keys``)."""
from __future__ import annotations

import argparse
import gc
import logging
import os
import signal
import sys
import time

from daemon import assembly, keys_cli
from daemon.latency import qualify
from daemon.loop.clock import MonotonicClock
from daemon.loop.cycle import ControlLoop
from daemon.loop.watchdog import CycleWatchdog
from daemon.loop.port import DEFAULT_COMMAND, DEFAULT_CONTROL, DEFAULT_TELEMETRY, ZmqServer
from daemon.messenger.process import MessengerError
from daemon.planner.process import BUILD_NICE, DEFAULT_TIME_LIMIT_S
from daemon.service import host, realtime
from daemon.service.notify import Notifier
from hal import config
from hal.declare import declare, summary
from hal.errors import ConfigError, TransportError
from hal.rig import RigIO
from hal.taxel_array import load_frame_source
from hal.transport import create_transport

log = logging.getLogger("pneumad")


def check_config(args) -> int:
    """``pneumad --check``: what a start would refuse, found without opening anything: the rig
    file read and validated, its transport built (its backend and options; a transport is
    built before it is opened, so nothing is touched) and the devices on its channels, the
    contact sensor's frame source found, the starting controller built on it (with the joints'
    models); a summary printed."""
    rig = assembly.rig_of(args)
    transport = create_transport(rig, time.monotonic)
    RigIO(rig, transport)
    if rig.contact_sensor is not None:
        try:
            load_frame_source(rig.contact_sensor.source)
        except LookupError as exc:
            raise ConfigError(f"contact_sensor.source: {exc}") from None
    plugins = assembly.controller_plugins(args.controller_plugin)
    dirs = assembly.controller_dirs(args, rig, plugins)
    for refused in dirs.refused:
        print(f"controller file {refused['file']} refused: {refused['error']}", file=sys.stderr)
    parts = assembly.loop_parts(rig, args.period, args.controller, plugins, dirs=dirs)
    print(f"{rig.origin}: rig {rig.rig.name!r} ({rig.hash[:12]}), transport {rig.transport.backend}, "
          f"controller {assembly.starting_controller(args.controller, rig)}")
    lines = summary(declare(rig, [ch.name for ch in transport.outputs], parts.actuation))
    for line, j in zip(lines, rig.joints):
        print(f"  {line}")
        params = rig.joint_params(j)
        if j.muscles is not None:
            m = j.muscles
            print(f"    muscle pair ({m.per_side} a side, L0 {m.rest_length_mm:g} mm, pulley {m.pulley_radius_mm:g} mm), "
                  f"link {j.link.mass_kg:g} kg" + (f", MR brake {j.brake.max_nm:g} N m" if j.brake is not None else ""))
        elif j.linear_axis is not None:
            a = j.linear_axis
            print(f"    cylinder bore {a.bore_m * 1e3:g} mm, rod {a.rod_m * 1e3:g} mm, stroke {a.stroke_m * 1e3:g} mm, "
                  f"{a.moving_mass_kg:g} kg moving, valve {a.nominal_flow_l_min:g} l/min")
        elif j.kind == "rotary":
            print("    model " + (f"{j.model_name!r} (D {params.D:.4g} N m s/deg, T_dly {params.T_dly * 1e3:.1f} ms)"
                                  if params is not None else "none"))
    for line in lines[len(rig.joints):]:
        print(f"  {line}")
    safety, timing = rig.safety, rig.timing
    print(f"  safety: input stale after {safety.stale_after_s * 1e3:g} ms, a cycle woken "
          f"{safety.stall_after_s * 1e3:g} ms late trips")
    print(f"  timing: degraded below {timing.min_rate_fraction:.0%} of the rate, {timing.max_overrun_fraction:.1%} of "
          f"deadlines missed or a step over {timing.step_budget_fraction:.0%} of the period (over "
          f"{timing.window_s:g} s); policy {timing.policy}")
    for name, words in simulated_faults(transport):
        print(f"  simulator: joint {name}: {words} (an injected fault: docs/model.md)")
    if rig.arm.link_lengths_mm:
        print(f"  arm: links {', '.join(f'{l:g}' for l in rig.arm.link_lengths_mm)} mm, gravity in its plane "
              f"({', '.join(f'{g:g}' for g in rig.arm.gravity_m_s2)}) m/s^2")
    if rig.contact_sensor is not None:
        sensor = rig.contact_sensor
        print(f"  contact sensor: {sensor.source} pad, {sensor.rate_hz:g} frames/s, {len(sensor.dead)} dead taxel(s), "
              f"estimator memory {sensor.memory_ms:g} ms (beta {sensor.beta_memory_ms:g} ms)")
    return 0


def simulated_faults(transport) -> list[tuple[str, str]]:
    """The simulator's injected faults, per joint (none on another transport)."""
    joints = getattr(getattr(transport, "options", None), "joints", None) or {}
    return [(name, jo.drift_words()) for name, jo in joints.items() if getattr(jo, "drift_words", None)
            and jo.drift_words()]


def cmd_run(args) -> int:
    if args.check:
        return check_config(args)
    rig, plugins = assembly.rig_of(args), assembly.controller_plugins(args.controller_plugin)  # bad ones: exit 2, nothing bound
    dirs = assembly.controller_dirs(args, rig, plugins)  # their files loaded now, before the loop runs
    clock = MonotonicClock(spin_s=args.spin_us * 1e-6)
    sys.setswitchinterval(args.gil_switch_us * 1e-6)
    with assembly.planner(args.prepare_limit_s) as (preparer, warming), assembly.messenger(args, rig) as server:
        # systemctl reload: the messenger reads its allow-list again.
        signal.signal(signal.SIGHUP, lambda *_: server.messenger.reload_keys())
        warming.result(timeout=120)
        loop = assembly.build_loop(rig, clock, args.period, args.controller, plugins, server.publish,
                                   stats_banks=server.stats_banks, dirs=dirs)
        server.attach(loop, preparer)
        return _run_loop(args, loop, server)


def _run_loop(args, loop: ControlLoop, server: ZmqServer) -> int:
    notifier = Notifier()
    stop_reason = []

    def on_signal(signum, _frame):
        stop_reason.append(signal.Signals(signum).name)
        loop.stop()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    def heartbeat(lp: ControlLoop) -> None:
        if lp.healthy:
            notifier.watchdog()
        notifier.status(f"{lp.state.value}; controller {lp.controller.name}; cycle {lp.cycle}; "
                        f"overruns {lp.stats.overruns_total}")

    loop.heartbeat = heartbeat
    loop.stats_period = args.stats_period
    if server.security["warning"]:
        log.warning("%s", server.security["warning"])
    if notifier.watchdog_interval:
        loop.heartbeat_interval = min(1.0, notifier.watchdog_interval)
    for warning in assembly.realtime_setup(args):
        log.warning(warning)
    log.log(*host.start_verdict(realtime.describe(), args.no_rt))  # one line: what this PC grants the loop
    gc.collect()
    gc.freeze()  # start-up objects never scanned again
    gc.disable()  # and no collection inside the loop
    loop.start()
    watchdog = CycleWatchdog(loop, server.watchdog_link)  # writes the safe state when the loop cannot
    watchdog.start()
    log.info("pneumad %s: rig %s (%s), %s, period %.3f ms; commands %s, control %s, telemetry %s",
             "running", loop.rig.rig.name, loop.rig.origin, realtime.describe(), args.period * 1e3,
             *server.endpoints.values())
    notifier.ready(f"{loop.state.value}; rig {loop.rig.rig.name}")
    try:
        loop.run()
    finally:
        notifier.stopping()
        watchdog.stop()
        loop.shutdown(stop_reason[0] if stop_reason else "exit")
        gc.enable()
        log.info("stopped (%s): safe state written", stop_reason[0] if stop_reason else "exit")
    return 0


def cmd_safe_state(args) -> int:
    """Write the configured safe state through the transport once, in a fresh process."""
    io = assembly.open_rig(assembly.rig_of(args), time.monotonic)
    rig, transport = io.config, io.transport
    try:
        io.write_safe()
        print(f"safe state written to {rig.rig.name} via {transport.backend}: "
              + ", ".join(f"{ch.name}={v:.3f} V" for ch, v in zip(transport.outputs, io.safe_volts)))
    finally:
        transport.close()
    return 0


def cmd_keys(args) -> int:
    return keys_cli.run(args)


def cmd_latency(args) -> int:
    return qualify(args)


def _positive(text: str) -> float:
    """An argparse type: a number of seconds above zero."""
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be above 0, not {text}")
    return value


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="pneumad", description=__doc__)
    sub = p.add_subparsers(dest="command_name", required=True)

    def common(sp):
        sp.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
        sp.add_argument("--config", default=None,
                        help=f"rig file, or a built-in rig name ({', '.join(config.BUILTIN_RIGS)}); default: the "
                             "simulated 2-joint rig")
        sp.add_argument("--transport", default=None,
                        help="reach the rig through this backend instead of its file's (sim, serial, modbus, can, "
                             "or module:Class)")
        sp.add_argument("--transport-option", action="append", default=[], metavar="KEY=VALUE",
                        help="an option of that backend, repeatable: e.g. port=/tmp/pneumad-bridge; without "
                             "--transport, one of the rig file's own transport replaced: e.g. compiled=true")
        sp.add_argument("--safety", action="append", default=[], metavar="KEY=VALUE",
                        help="replace a value of the rig file's [safety] for this run, repeatable, checked as the "
                             "file's own: e.g. stale_after_s=0.05 across a wire on a PC without real-time scheduling")

    def timing(sp):
        sp.add_argument("--period", type=float, default=0.001, help="loop period [s] (default 0.001)")
        sp.add_argument("--rt-priority", type=int, default=80, help="SCHED_FIFO priority (default 80)")
        sp.add_argument("--cpus", type=lambda s: [int(c) for c in s.split(",")], default=None,
                        help="CPU affinity, e.g. 1 or 2,3")
        sp.add_argument("--no-rt", action="store_true", help="no SCHED_FIFO, no mlockall, no cpu_dma_latency")
        sp.add_argument("--cpu-dma-latency-us", type=int, default=0,
                        help="hold /dev/cpu_dma_latency at this [us] while running, keeping idle CPUs out of "
                             "deep sleep (default 0: poll, as cyclictest does; -1 leaves the system's setting)")
        sp.add_argument("--spin-us", type=float, default=200.0, help="spin this long before each deadline [us]")
        sp.add_argument("--controller", default=None, help="controller active at start (default: the rig file's "
                                                             "[rig] controller, else pid; a registered name, or module:Class)")
        sp.add_argument("--controller-plugin", action="append", default=[], metavar="NAME=module:Class",
                        help="make a third-party controller available to requests under NAME, repeatable (requests "
                             "name registered controllers only: never a module to import)")
        sp.add_argument("--controller-dir", action="append", default=[], metavar="DIR",
                        help="load every controller defined in DIR's *.py files, repeatable (beside the rig file's "
                             "[rig] controller_dirs); controller.reload NAME reads a file again without a restart")
        sp.add_argument("--gil-switch-us", type=float, default=5000.0,
                        help="sys.setswitchinterval [us] (default 5000, Python's own): how soon another Python "
                             "thread can take the GIL from the loop mid-cycle. Shorter measured worse "
                             "(docs/benchmarks.md): the loop hands over the GIL and then waits to get it back")

    run = sub.add_parser("run", help="run the daemon (the default)")
    common(run)
    timing(run)
    run.add_argument("--check", action="store_true",
                     help="read and validate the rig file, build the controller on it, print a summary, and exit")
    run.add_argument("--command", default=DEFAULT_COMMAND, help=f"command endpoint (default {DEFAULT_COMMAND})")
    run.add_argument("--control", default=DEFAULT_CONTROL, help=f"control endpoint (default {DEFAULT_CONTROL})")
    run.add_argument("--telemetry", default=DEFAULT_TELEMETRY, help=f"telemetry endpoint (default {DEFAULT_TELEMETRY})")
    run.add_argument("--prepare-limit-s", type=_positive, default=DEFAULT_TIME_LIMIT_S,
                     help="a plan or controller build beside the loop that takes longer than this [s] is taken as "
                          f"hung and stopped (default {DEFAULT_TIME_LIMIT_S:g}; builds run at nice {BUILD_NICE}, so a PC busy "
                          "with other work may need more); clients read it from describe")
    run.add_argument("--stats-period", type=float, default=1.0, help="window of the stats telemetry [s] (default 1)")
    run.add_argument("--keys", default=None, metavar="DIR",
                     help="CURVE key directory (pneumad keys init): every client must hold an allowed key")
    run.add_argument("--insecure", action="store_true",
                     help="allow binding past loopback without keys (anyone who reaches the port can move the arm)")
    run.add_argument("--record-dir", default=os.path.join(os.environ.get("STATE_DIRECTORY", "").split(":")[0], "recordings"),
                     help="where record.start and `path --record` write MCAP files (default ./recordings, or "
                          "$STATE_DIRECTORY/recordings under systemd; 'none': the daemon records nothing)")
    run.add_argument("--record-max-mb", type=float, default=2048.0, help="a recording ends at this size (default 2048)")
    run.add_argument("--record-min-free-mb", type=float, default=200.0,
                     help="recordings end when the disk has less than this left (default 200)")
    run.add_argument("--plotjuggler", default=None, metavar="ENDPOINT",
                     help="also publish one msgpack row per cycle, with its own time field 't', for PlotJuggler's "
                          "ZMQ Subscriber (e.g. tcp://127.0.0.1:9872; docs/protocol.md, PlotJuggler)")
    run.add_argument("--foxglove", default=None, metavar="HOST:PORT",
                     help="also serve a live Foxglove WebSocket stream (e.g. 127.0.0.1:8765; loopback unless "
                          "--insecure; docs/recordings.md, Live): joint states, set-points, commands, pressures, "
                          "internals, loop timing, events; read-only")
    safe = sub.add_parser("safe-state", help="write the rig's safe state once and exit (dead-man path)")
    common(safe)
    lat = sub.add_parser("latency", help="qualify this PC: run the loop on the simulator and judge its latency")
    common(lat)
    timing(lat)
    lat.add_argument("--seconds", type=float, default=10.0)
    keys_cli.add_parser(sub)
    return p


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in ("run", "safe-state", "latency", "keys", "-h", "--help"):
        argv = ["run", *argv]  # plain `pneumad [options]` runs the daemon
    args = parser().parse_args(argv)
    logging.basicConfig(level=getattr(args, "log_level", "INFO"), format="%(name)s %(levelname)s: %(message)s")
    handlers = {"run": cmd_run, "safe-state": cmd_safe_state, "latency": cmd_latency, "keys": cmd_keys}
    try:
        return handlers[args.command_name](args)
    except ConfigError as exc:
        log.error("configuration: %s", exc)
        return 2
    except TransportError as exc:
        log.error("transport: %s", exc)
        return 3
    except MessengerError as exc:
        log.error("endpoints: %s", exc)
        return 4


if __name__ == "__main__":
    sys.exit(main())
