"""The one assembler: a rig and the daemon's options -> transport, RigIO, the joints' command
interfaces, the controllers' context, the loop, and the services around it (the messenger's
sockets, the planner worker, the contact sensor, telemetry).

``pneumad run``, ``pneumad --check``, ``pneumad latency``, the benches and the test harness
(:mod:`daemon.testing`) all build through here, so a part added to the loop is wired once.
Everything is built before the loop runs: nothing here runs in a cycle.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from contextlib import contextmanager
import time

from pathlib import Path

from controllers import directory, registry
from controllers.base import ControllerContext
from daemon.contact.process import ContactSensor
from daemon.loop.cycle import ControlLoop
from daemon.loop.feed_forward import LoadFeedForward
from daemon.loop.parts import LoopParts
from daemon.loop.port import ZmqServer
from daemon.loop.safety import Supervisor
from daemon.loop.stats import LoopStats
from daemon.loop.telemetry import Telemetry
from daemon.loop.tracking import TrackingGuard
from daemon.messenger.shared import STALL_S
from daemon.planner.process import DEFAULT_TIME_LIMIT_S, Preparer
from daemon.service import realtime
from daemon.wire.cycle_layout import CycleLayout
from daemon.wire.loop_stats import StatsBanks
from hal import config
from hal.declare import declare
from hal.actuation import RigActuation
from hal.errors import ConfigError
from hal.rig import PressureDrivers, RigIO
from hal.transport import create_transport

# a telemetry sink: (topic, payload); the payload is bytes-like and valid only during the call
Publish = Callable[[bytes, bytes | bytearray | memoryview], None]


def rig_of(args) -> config.RigConfig:
    """The rig ``pneumad``'s options name: ``--config`` (a file or a built-in rig), its
    transport replaced by ``--transport`` (with its ``--transport-option KEY=VALUE``) if given,
    else its transport's options replaced by any ``--transport-option``, and ``[safety]`` values by ``--safety KEY=VALUE``."""
    rig = config.load(args.config)
    options = dict(map(config.parse_option, args.transport_option))
    if args.transport:
        rig = config.with_transport(rig, args.transport, options)
    elif options:  # the rig file's own transport, these of its options replaced
        rig = config.with_transport(rig, rig.transport.backend, {**rig.transport.options, **options})
    if args.safety:
        rig = config.with_safety(rig, dict(config.parse_option(text, "--safety") for text in args.safety))
    return rig


def controller_plugins(items: Sequence[str]) -> dict[str, str]:
    """``--controller-plugin NAME=module:Class`` options as a name -> path map."""
    plugins = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name.strip() or ":" not in path:
            raise ConfigError(f"--controller-plugin {item!r}: expected NAME=module:Class")
        plugins[name.strip()] = path.strip()
    return plugins


def controller_dirs(args, rig: config.RigConfig, plugins: dict[str, str]) -> directory.Directories:
    """The controller directories the rig file (``[rig] controller_dirs``, relative to the
    file) and ``--controller-dir`` name, their files loaded (:mod:`controllers.directory`); their
    controllers are added to ``plugins``. A file that fails is refused (said at start, in
    status.controllers_refused), a directory that does not exist is a ConfigError."""
    base = Path(rig.origin).parent if not rig.origin.startswith(("builtin:", "<")) else Path.cwd()
    dirs = [base / d for d in rig.rig.controller_dirs] + [Path(d) for d in getattr(args, "controller_dir", [])]
    try:
        found = directory.scan(dirs, registry.available(plugins))
    except directory.PluginError as exc:
        raise ConfigError(f"--controller-dir: {exc}") from None
    plugins.update(found.plugins())
    return found


def starting_controller(requested: str | None, rig: config.RigConfig) -> str:
    """``requested`` (``--controller``), else the one the rig file names (``[rig] controller``), else pid."""
    return requested or rig.rig.controller or "pid"


def loop_parts(rig: config.RigConfig, period: float = 0.001, controller: str | None = None,
               plugins: dict[str, str] | None = None, drivers: PressureDrivers | None = None,
               dirs: directory.Directories | None = None) -> LoopParts:
    """What the loop is made of, built on ``rig`` without opening anything (``--check`` stops
    here). A controller that cannot be built is a ConfigError naming the option or setting.
    ``dirs``: the controller directories' files (their controllers are in ``plugins`` too)."""
    plugins = dict(plugins or {})
    actuation = RigActuation(rig, drivers)
    context = ControllerContext.for_rig(rig, actuation, period)
    try:
        registry.check_defaults(context, plugins)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    try:
        active = registry.build(starting_controller(controller, rig), context, plugins=plugins)
    except (LookupError, ValueError) as exc:  # ParamError is a ValueError
        raise ConfigError(f"--controller: {exc}") from None
    safety = rig.safety
    fallback = None
    if safety.tracking_action == "fallback" or rig.timing.policy == "hold":  # the tracking rule's, the timing policy's
        try:
            fallback = registry.build(safety.fallback_controller, context, plugins=plugins)
        except (LookupError, ValueError) as exc:
            raise ConfigError(f"safety.fallback_controller: {exc}") from None
    names = tuple(j.name for j in rig.joints)
    return LoopParts(actuation, context, Supervisor(rig, period), active, fallback,
                     TrackingGuard(names, safety.tracking_error_deg, safety.tracking_window_s, safety.tracking_error_mm,
                                   tuple(j.position_unit for j in rig.joints)),
                     LoadFeedForward(context), plugins, dirs or directory.Directories())


def cycle_layout(rig: config.RigConfig, outputs: Sequence[str] | None = None,
                 actuation: RigActuation | None = None) -> CycleLayout:
    """The cycle record's layout on ``rig`` (:mod:`daemon.wire.cycle_layout`), whose transport
    writes ``outputs`` (default: the channels its transport declares, built but not opened)."""
    if outputs is None:
        outputs = [ch.name for ch in create_transport(rig, time.monotonic).outputs]
    return CycleLayout.of(declare(rig, outputs, actuation))


def open_rig(rig: config.RigConfig, now: Callable[[], float], drivers: PressureDrivers | None = None) -> RigIO:
    """The rig's transport created (samples stamped by ``now`` [s]) and opened, behind its
    device drivers."""
    transport = create_transport(rig, now)
    transport.open()
    try:
        return RigIO(rig, transport, drivers)
    except Exception:
        transport.close()
        raise


def build_loop(rig: config.RigConfig, clock, period: float = 0.001, controller: str | None = None,
               plugins: dict[str, str] | None = None, publish: Publish | None = None,
               contact: bool = True, stats_banks: StatsBanks | None = None,
               dirs: directory.Directories | None = None) -> ControlLoop:
    """The loop on ``rig``, its transport open; telemetry to ``publish`` if given, its timing
    counted into ``stats_banks`` if given (a port's, which its messenger summarises); the rig's
    contact sensor's process started when it has one and ``contact`` (an in-process loop on
    a virtual clock leaves it out: its frames come in real time). Each regulator's driver
    is built once, for the I/O and the command interfaces both. The cycle record's layout is
    built here once, from the rig's declared interfaces (its messenger's port, built before,
    checks it has the same: :meth:`daemon.loop.port.ZmqServer.attach`)."""
    drivers = PressureDrivers.of(rig)
    parts = loop_parts(rig, period, controller, plugins, drivers, dirs)
    io = open_rig(rig, clock.now, drivers)
    try:
        layout = cycle_layout(rig, [ch.name for ch in io.transport.outputs], parts.actuation)
    except Exception:
        io.transport.close()
        raise
    sensor = None
    if contact and rig.contact_sensor is not None:
        sensor = ContactSensor(rig.contact_sensor, clock.now)
        try:
            sensor.open()
        except Exception:
            io.transport.close()
            raise
    return ControlLoop(io, clock, parts, layout, telemetry=Telemetry(publish, layout) if publish is not None else None,
                       contact_sensor=sensor, stats=LoopStats(stats_banks))


def loop_from_args(args, clock, publish: Publish | None = None, stats_banks: StatsBanks | None = None) -> ControlLoop:
    """:func:`build_loop` with ``pneumad``'s options (run, latency)."""
    return build_loop(rig_of(args), clock, args.period, args.controller, controller_plugins(args.controller_plugin),
                      publish, stats_banks=stats_banks)


def realtime_setup(args) -> list[str]:
    """The real-time set-up ``pneumad``'s timing options ask for (none of it with --no-rt); its warnings."""
    idle_latency = None if args.no_rt or args.cpu_dma_latency_us < 0 else args.cpu_dma_latency_us
    return realtime.setup(None if args.no_rt else args.rt_priority, args.cpus, not args.no_rt, idle_latency)


def stall_watch_s(rig: config.RigConfig) -> float:
    """How long the messenger lets the loop go without a cycle before it answers for it
    (``loop_stalled``) [s]: 0.5 s, or twice the rig's own ``[safety] stall_after_s`` where that
    is longer. A loop woken late trips itself at ``stall_after_s`` and cycles on; the messenger
    must not refuse requests for a pause the rig file allows."""
    return max(STALL_S, 2.0 * rig.safety.stall_after_s)


@contextmanager
def messenger(args, rig: config.RigConfig) -> Iterator[ZmqServer]:
    """The messenger's sockets from ``pneumad run``'s options, closed on the way out. Made
    before the real-time set-up: the messenger keeps normal priority and every CPU."""
    recording = None if args.record_dir == "none" else {"directory": args.record_dir, "max_mb": args.record_max_mb,
                                                         "min_free_mb": args.record_min_free_mb, "flight": rig.flight_recorder}
    server = ZmqServer(args.command, args.control, args.telemetry, keys=args.keys, insecure=args.insecure,
                       recording=recording, plotjuggler=args.plotjuggler,
                       foxglove=args.foxglove, loop_stall_s=stall_watch_s(rig), timing=rig.timing,
                       layout=cycle_layout(rig), model=rig)
    try:
        yield server
    finally:
        server.close()


@contextmanager
def planner(time_limit_s: float = DEFAULT_TIME_LIMIT_S) -> Iterator[tuple[Preparer, Future]]:
    """The planner worker, spawned, and its warm-up under way: the caller starts the messenger
    meanwhile (the two start-ups side by side, not one after the other) and waits on the
    future before the transport opens (a process starting beside a running wire delayed its
    replies). Closed on the way out."""
    preparer = Preparer(time_limit_s)
    try:
        yield preparer, preparer.warm()
    finally:
        preparer.close()
