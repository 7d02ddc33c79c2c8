"""The Foxglove channels: one set of topics and schemas for the live stream
(``pneumad run --foxglove``, :mod:`daemon.messenger.foxglove_stream`) and the recordings
(:mod:`daemon.recordings.mcap_log` writes them beside its ``/pneumad/<topic>`` channels), so
one layout (docs/foxglove-layout.json) serves live and recorded data.

From the telemetry as subscribers see it (``state`` columns, ``internals``, ``stats``,
``event``, ``contact``, ``model``), :class:`Frames` makes (topic, log time [ns], encoded message):

Every per-cycle channel is made from the cycle record's fields (:mod:`daemon.wire.cycle_layout`,
the describe's ``cycle_layout``), so a field a rig declares reaches its channel with no code
for that rig:

- ``/joint_states``: ``foxglove.JointStates`` (protobuf), one per loop cycle: per joint (named
  as the rig file names it) position [rad or m], velocity [rad/s or m/s] and effort, the commanded
  chamber pressure difference head - rod (a muscle pair's a - b) [Pa] (NaN on a joint that
  commands no pressures): the torque needs a moment arm and areas the daemon does not publish,
  the pressure difference is what drives the joint.
- JSON-schema channels, one message per cycle: ``/pneumad/tracking`` (position, set-point,
  error, velocity in the unit a person reads each joint in: ``position_deg`` on a rotary joint,
  ``position_mm`` on a linear one; the loop's mode and the reference's phase: approach, settle,
  path or hold), ``/pneumad/commands`` (each command interface in force with its limits: V_MV
  [V], a muscle pair's pressures [Pa], brake [N m], a 5/3 valve [V]; null outside ``enabled``;
  the output volts actually written; ``output`` says ``safe state`` whenever the safe state is
  written instead of the controller's output), ``/pneumad/commanded_pressures`` (each chamber's
  pressure command after the clamps [kPa], ``p_<chamber>_cmd_kpa``), and where the rig has
  them, ``/pneumad/measured_pressures`` (each chamber transmitter's reading [kPa],
  ``p_<chamber>_kpa``) and ``/pneumad/sensors`` (every other sensor in its SI unit: the rig's by
  name, ``force``, ``supply_pressure``, a further input; a joint's further inputs under
  ``joints.<name>``); ``/pneumad/tip`` (forward
  kinematics of the first two joints [mm], measured and set-point, on a rig with link lengths);
  and one per message: ``/pneumad/controller`` (the internals, each signal's unit from the
  controller that published it), ``/pneumad/loop`` (timing), ``/pneumad/contact_estimate``,
  ``/pneumad/model_residual`` (the model beside the arm: each joint's residual statistics, docs/model.md).
- ``/log`` (``foxglove.Log``) and ``/events`` (``foxglove.Event``) for the daemon's events:
  trips, switches, references starting and ending (an ending's event spans the reference).

Log times are the daemon's monotonic clock [ns], as the recordings' other channels.
"""
from __future__ import annotations

import json
import math

import orjson
from foxglove.messages import Event, JointState, JointStates, KeyValuePair, Log, LogLevel, Timestamp

from daemon.recordings.legacy import layout_of
from daemon.wire.cycle_layout import CycleLayout

JOINT_STATES, LOG, EVENTS = "/joint_states", "/log", "/events"
TRACKING, COMMANDS, TIP = "/pneumad/tracking", "/pneumad/commands", "/pneumad/tip"
COMMANDED_PRESSURES, MEASURED_PRESSURES = "/pneumad/commanded_pressures", "/pneumad/measured_pressures"
SENSORS = "/pneumad/sensors"
TRACKED = ("position", "setpoint", "error", "velocity")  # a joint's tracking channel's quantities
CONTROLLER, LOOP, CONTACT = "/pneumad/controller", "/pneumad/loop", "/pneumad/contact_estimate"
MODEL = "/pneumad/model_residual"  # the model beside the arm: each joint's residual statistics (docs/model.md)
MODEL_FIGURES = ("rms", "mean", "max_abs", "residual", "band")  # per joint, in its unit (_deg, _mm); residual: the latest
SAFE_STATE = "safe state"
ERRORS = ("trip", "estop", "loop_stalled", "watchdog")  # event kinds logged as errors; warnings below
WARNINGS = ("tracking", "experiment", "unleased", "lease_revoked", "messenger", "recorder", "recover", "model")
_PROTOBUF = {JOINT_STATES: JointStates, LOG: Log, EVENTS: Event}

_NUMBER = {"type": ["number", "null"]}  # null: not finite, or not measured (json_bytes)
_TIME = {"type": "number"}  # [s] on the daemon's clock


def _obj(properties: dict, title: str = "") -> dict:
    schema = {"type": "object", "properties": properties}
    return {"title": title, **schema} if title else schema


def _numbers(*names: str) -> dict:
    return _obj({n: _NUMBER for n in names})


def unit_key(unit: str) -> str:
    """A unit as the end of a key: ``deg/s`` -> ``deg_s``."""
    return unit.replace("/", "_").replace(" ", "_")


class ChannelFields:
    """Which of a layout's fields each per-cycle channel carries, under which key."""

    def __init__(self, layout: CycleLayout):
        self.layout = layout
        self.joints = layout.owners()
        # per joint: (field, key, scale) in the unit a person reads it in (deg, mm ...)
        self.tracking = {j: [(f.name, f"{f.quantity}_{unit_key(f.display[0])}", f.display[1])
                             for f in layout.of_joint(j) if f.quantity in TRACKED] for j in self.joints}
        self.commands = {j: [(f.name, f.quantity[2:]) for f in layout.of_joint(j, "command")] for j in self.joints}
        self.commanded = {j: [(f.name, f"{f.quantity}_kpa") for f in layout.of_joint(j, "commanded")]
                          for j in self.joints}
        self.measured = {j: [(f.name, f"{f.quantity}_kpa") for f in layout.of_joint(j, "measured")
                             if f.quantity.startswith("p_") and f.unit == "Pa"] for j in self.joints}
        chambers = {name for pairs in self.measured.values() for name, _ in pairs}
        others = [f for f in layout.of_group("measured") if f.quantity not in ("position", "velocity")
                  and f.name not in chambers]
        self.sensors = [f.name for f in others if not f.owner]  # the rig's, by name
        self.inputs = {j: [(f.name, f.quantity) for f in others if f.owner == j] for j in self.joints}  # a joint's
        self.outputs = [(f.name, f.quantity[4:]) for f in layout.of_group("output")]
        # the unit of each joint's model residual (docs/model.md): mm on a linear axis, deg on a rotary joint
        self.model_unit = {j: "mm" if layout[f"{j}.position"].unit == "m" else "deg" for j in self.joints}

    def effort(self, joint: str) -> tuple[str, str] | None:
        """A joint's (first, second) commanded chamber pressure fields, if it commands pressures."""
        pair = self.commanded[joint]
        return (pair[0][0], pair[1][0]) if len(pair) == 2 else None


def json_schemas(describe: dict) -> dict[str, dict]:
    """Each JSON channel's schema for this daemon's rig (joints by name, the fields of its cycle
    layout); ``/pneumad/measured_pressures`` and ``/pneumad/sensors`` only where the rig has them."""
    fields = ChannelFields(layout_of(describe))
    layout = fields.layout
    per_joint = lambda keys: _obj({j: _numbers(*keys(j)) for j in fields.joints})  # noqa: E731
    stamp = {"t": _TIME, "cycle": {"type": "integer"}}
    figures = _numbers("p50", "p99", "p99.9", "max")
    schemas = {
        TRACKING: _obj({**stamp, "mode": {"type": "string"}, "phase": {"type": "string"},
                        "joints": per_joint(lambda j: [k for _, k, _ in fields.tracking[j]])},
                       "position, set-point, tracking error and velocity per joint, in the unit a person reads it "
                       "in (deg or mm); the loop's mode, the reference's phase"),
        COMMANDS: _obj({**stamp, "output": {"type": "string"},
                        "joints": per_joint(lambda j: [f"{c}{s}" for _, c in fields.commands[j]
                                                       for s in ("", "_min", "_max")]),
                        "written_volts": _obj({ch: _NUMBER for _, ch in fields.outputs})},
                       "command interfaces in force and their limits (V_MV [V], pressures [Pa], brake [N m], "
                       "valve [V]); output volts written; output: controller or safe state"),
        COMMANDED_PRESSURES: _obj({**stamp, "joints": per_joint(lambda j: [k for _, k in fields.commanded[j]])},
                                  "chamber pressures COMMANDED [kPa], after the rig's limits (a muscle pair: a, b); "
                                  "not measured"),
    }
    if any(fields.measured.values()):
        schemas[MEASURED_PRESSURES] = _obj({**stamp, "joints": per_joint(lambda j: [k for _, k in fields.measured[j]])},
                                           "chamber pressures MEASURED by their transmitters [kPa]")
    if fields.sensors or any(fields.inputs.values()):
        named = fields.sensors + [name for pairs in fields.inputs.values() for name, _ in pairs]
        schemas[SENSORS] = _obj({**stamp, **{n: _NUMBER for n in fields.sensors},
                                 "joints": _obj({j: _numbers(*(q for _, q in pairs))
                                                 for j, pairs in fields.inputs.items() if pairs})},
                                "every other sensor in its SI unit, the rig's by name, a joint's under joints: "
                                + ", ".join(f"{n} [{layout[n].unit}]" for n in named))
    schemas.update({
        TIP: _obj({**stamp, **_numbers("x_mm", "y_mm", "setpoint_x_mm", "setpoint_y_mm")["properties"]},
                  "tip position by forward kinematics of the first two joints [mm]"),
        CONTROLLER: _obj({**stamp, "controller": {"type": "string"},
                          "signals": _obj({}), "units": _obj({})},
                         "the active controller's internal signals per joint, units from that controller"),
        LOOP: _obj({"t": _TIME, "cycles": {"type": "integer"}, "overruns": {"type": "integer"},
                    "latency_us": figures, "compute_us": figures}, "loop timing over a stats window [us]"),
        CONTACT: _obj({"t": _TIME, "frame": {"type": "integer"}, "age_s": _NUMBER,
                       "contact": {"type": ["object", "null"]}}, "the array sensor's contact estimate"),
        MODEL: _obj({"t": _TIME, "band_deg": _NUMBER,
                     "joints": _obj({j: _obj({**_numbers(*(f"{k}_{fields.model_unit[j]}" for k in MODEL_FIGURES))[
                                     "properties"], "drift": {"type": "boolean"}}) for j in fields.joints})},
                    "the model beside the arm: each joint's residual (measured - predicted) over the last window "
                    "[deg; a linear axis: mm, its _mm keys], the latest residual, the band (the rig file's; each joint's in force), whether the joint has "
                    "drifted out of it"),
    })
    return schemas


def schema_name(topic: str) -> str:
    """A JSON channel's schema name, live and recorded: ``pneumad.tracking`` for ``/pneumad/tracking``."""
    return "pneumad." + topic.rsplit("/", 1)[-1]


def protobuf_schemas() -> dict[str, tuple[str, bytes]]:
    """The Foxglove-standard channels: topic -> (schema name, FileDescriptorSet)."""
    return {topic: (cls.get_schema().name, cls.get_schema().data) for topic, cls in _PROTOBUF.items()}


def signal_units(describe: dict, controller: str) -> dict[str, str]:
    """Each internal signal's unit as ``controller`` declares it (describe's controllers): never
    another controller's signal of the same name."""
    for c in describe.get("controllers", []):
        if isinstance(c, dict) and c.get("name") == controller:
            return {s["name"]: s.get("unit", "-") for s in c.get("internals", [])}
    return {}


def ns(t: float) -> int:
    return max(int(round(t * 1e9)), 0)


def _stamp(t: float) -> Timestamp:
    whole = math.floor(t)
    return Timestamp(max(int(whole), 0), min(int(round((t - whole) * 1e9)), 999_999_999))


def json_bytes(message: dict) -> bytes:
    """A JSON channel's message, compact (every JSON channel of a recording and of the live
    stream). JSON has no NaN or infinity (RFC 8259) and the viewers parse it strictly
    (Foxglove's ``JSON.parse``): a number that is not finite is written ``null``, as orjson
    writes it. orjson, not the standard library: a recording writes five JSON messages a cycle,
    and the standard encoder was half a recording's cost (docs/benchmarks.md, "The recorder").
    What orjson refuses (a key that is not a string, an integer past 64 bits) goes the standard
    way."""
    try:
        return orjson.dumps(message)
    except orjson.JSONEncodeError:
        return json.dumps(_finite(message), allow_nan=False, separators=(",", ":")).encode()


def _finite(value):
    """``value`` with every float that is not finite replaced by None (JSON's null)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


class Frames:
    """Telemetry -> Foxglove channel messages for one daemon (its ``describe``)."""

    def __init__(self, describe: dict):
        self.describe = describe
        self.fields = fields = ChannelFields(layout_of(describe))
        self.joints = fields.joints
        limits = {(c["joint"], c["name"]): (c.get("low"), c.get("high")) for c in describe.get("command_interfaces") or
                  [{"joint": j["name"], "name": "v_mv", "low": j.get("u_min_volts"), "high": j.get("u_max_volts")}
                   for j in describe["joints"]]}
        self._commands = {j: [(name, c, *limits.get((j, c), (None, None))) for name, c in fields.commands[j]]
                          for j in self.joints}
        lengths = describe.get("arm", {}).get("link_lengths_mm", [])
        rotary = [fields.layout[f"{j}.position"].unit == "rad" for j in self.joints[:2]]
        self._links = lengths[:2] if len(lengths) >= 2 and len(self.joints) >= 2 and all(rotary) else None
        self._efforts = [(j, fields.effort(j)) for j in self.joints]
        self._reference: tuple[float, float, float] | None = None  # start, approach end, end [s]
        self._settling = False  # a path's approach has ended and its clock has not started (its `settled` event)
        self._started: dict[int, float] = {}  # reference generation -> start [s]
        self._per_cycle = [(JOINT_STATES, self._joint_states), (TRACKING, self._tracking),
                           (COMMANDS, self._commands_in_force), (COMMANDED_PRESSURES, self._commanded),
                           (TIP, self._tip_position)]
        if any(fields.measured.values()):
            self._per_cycle.append((MEASURED_PRESSURES, self._measured))
        if fields.sensors or any(fields.inputs.values()):
            self._per_cycle.append((SENSORS, self._sensors))

    def state(self, m: dict, wanted=None, rows=None) -> list[tuple[str, int, bytes]]:
        """Per cycle of a ``state`` message: joint states, tracking, commands, commanded (and
        measured) pressures, sensors, tip (``wanted``: only these topics, e.g. those a client
        subscribed to; None: all; ``rows``: only these cycles of the batch, by index; None: all)."""
        makers = [(topic, make) for topic, make in self._per_cycle if wanted is None or topic in wanted]
        out = []
        for i in range(len(m["cycle"])) if rows is None else rows:
            stamp = ns(m["t"][i])
            for topic, make in makers:
                data = make(m, i)
                if data is not None:
                    out.append((topic, stamp, data))
        return out

    def _joint_states(self, m: dict, i: int) -> bytes:
        return JointStates(timestamp=_stamp(m["t"][i]), joints=[
            JointState(name=j, position=m[f"{j}.position"][i], velocity=m[f"{j}.velocity"][i],
                       effort=m[pair[0]][i] - m[pair[1]][i] if pair is not None else math.nan)
            for j, pair in self._efforts]).encode()

    def _tracking(self, m: dict, i: int) -> bytes:
        t = m["t"][i]
        return json_bytes({"t": t, "cycle": m["cycle"][i], "mode": m["mode"][i], "phase": self._phase(t),
                           "joints": {j: {key: m[name][i] * scale for name, key, scale in keys}
                                      for j, keys in self.fields.tracking.items()}})

    def _commands_in_force(self, m: dict, i: int) -> bytes:
        safe = m["mode"][i] != "enabled"  # outside enabled the safe state is written (the record: NaN, null here)
        joints = {j: {key: value for name, c, low, high in commands
                      for key, value in ((c, m[name][i]), (f"{c}_min", low), (f"{c}_max", high))}
                  for j, commands in self._commands.items()}
        return json_bytes({"t": m["t"][i], "cycle": m["cycle"][i], "output": SAFE_STATE if safe else "controller",
                           "joints": joints, "written_volts": {ch: m[name][i] for name, ch in self.fields.outputs}})

    def _commanded(self, m: dict, i: int) -> bytes:
        return json_bytes({"t": m["t"][i], "cycle": m["cycle"][i], "joints": {
            j: {key: m[name][i] / 1e3 for name, key in pairs} for j, pairs in self.fields.commanded.items()}})

    def _measured(self, m: dict, i: int) -> bytes:
        return json_bytes({"t": m["t"][i], "cycle": m["cycle"][i], "joints": {
            j: {key: m[name][i] / 1e3 for name, key in pairs} for j, pairs in self.fields.measured.items()}})

    def _sensors(self, m: dict, i: int) -> bytes:
        return json_bytes({"t": m["t"][i], "cycle": m["cycle"][i], **{n: m[n][i] for n in self.fields.sensors},
                           "joints": {j: {q: m[name][i] for name, q in pairs}
                                      for j, pairs in self.fields.inputs.items() if pairs}})

    def _tip_position(self, m: dict, i: int) -> bytes | None:
        if self._links is None:
            return None
        a, b = self.joints[:2]
        (x, y) = self._tip((m[f"{a}.position"][i], m[f"{b}.position"][i]))
        (sx, sy) = self._tip((m[f"{a}.setpoint"][i], m[f"{b}.setpoint"][i]))
        return json_bytes({"t": m["t"][i], "cycle": m["cycle"][i], "x_mm": x, "y_mm": y,
                           "setpoint_x_mm": sx, "setpoint_y_mm": sy})

    def _tip(self, q) -> tuple[float, float]:
        (l1, l2), a = self._links, q[0] + q[1]
        return l1 * math.cos(q[0]) + l2 * math.cos(a), l1 * math.sin(q[0]) + l2 * math.sin(a)

    def _phase(self, t: float) -> str:
        ref = self._reference
        if ref is None or t < ref[0]:
            return "hold"
        if t < ref[1]:
            return "approach"
        if self._settling:  # the path's start held until the arm settles there
            return "settle"
        return "path" if t <= ref[2] else "hold"

    def internals(self, m: dict) -> list[tuple[str, int, bytes]]:
        signals = {name: dict(zip(self.joints, values)) for name, values in m.get("signals", {}).items()}
        units = signal_units(self.describe, m.get("controller", ""))
        return [(CONTROLLER, ns(m["t"]), json_bytes({"t": m["t"], "cycle": m.get("cycle"),
                                                     "controller": m.get("controller"), "signals": signals,
                                                     "units": {s: units.get(s, "-") for s in signals}}))]

    def stats(self, m: dict) -> list[tuple[str, int, bytes]]:
        t = m.get("t", 0.0)
        return [(LOOP, ns(t), json_bytes({"t": t, "cycles": m.get("cycles"), "overruns": m.get("overruns"),
                                          "latency_us": m.get("latency_us", {}),
                                          "compute_us": m.get("compute_us", {}).get("total", {})}))]

    def contact(self, m: dict) -> list[tuple[str, int, bytes]]:
        t = m.get("t", m.get("frame_t", 0.0))
        return [(CONTACT, ns(t), json_bytes({**m, "t": t}))]

    def model(self, m: dict) -> list[tuple[str, int, bytes]]:
        """The ``model`` topic's statistics (its per-cycle residuals: the recording's ``/pneumad/model``)."""
        t = m.get("t", 0.0)
        joints = {}
        for name, j in (m.get("joints") or {}).items():
            u = j.get("unit", "deg")
            latest = [r for r in j.get(f"residual_{u}") or () if r is not None]
            joints[name] = {**{f"{k}_{u}": j.get(f"{k}_{u}") for k in MODEL_FIGURES[:3]},
                            f"residual_{u}": latest[-1] if latest else None,
                            f"band_{u}": j.get(f"band_{u}"), "drift": bool(j.get("flagged"))}
        return [(MODEL, ns(t), json_bytes({"t": t, "band_deg": m.get("band_deg"), "joints": joints}))]

    def event(self, m: dict) -> list[tuple[str, int, bytes]]:
        """A Log line and an Event: instantaneous, but a reference's end spans from its start."""
        t, kind = m.get("t", 0.0), m.get("kind", "?")
        start = t
        if kind == "reference":
            generation = m.get("generation", -1)
            if m.get("action") == "start":
                self._started[generation] = t
                duration = m.get("duration_s") or 0.0
                approach = m.get("approach_s") or 0.0
                self._reference = (t, t + approach, t + duration)
                self._settling = m.get("approach_s") is not None
            elif m.get("action") == "settled":  # the path's clock starts now, waited_s late
                self._settling = False
                if self._reference is not None:
                    self._reference = (self._reference[0], t, self._reference[2] + (m.get("waited_s") or 0.0))
            else:
                start = self._started.pop(generation, t)
                self._settling = False
                if self._reference is not None:
                    self._reference = (self._reference[0], self._reference[1], t)
        level = LogLevel.Error if kind in ERRORS else LogLevel.Warning if kind in WARNINGS else LogLevel.Info
        text = " ".join(f"{k}={v}" for k, v in m.items() if k not in ("t", "kind", "seq", "cycle") and v not in (None, ""))
        metadata = [KeyValuePair(key=k, value=str(v)) for k, v in m.items() if k != "t"]
        return [(LOG, ns(t), Log(timestamp=_stamp(t), level=level, message=f"{kind}: {text}", name="pneumad").encode()),
                (EVENTS, ns(t), Event(start_time=_stamp(start), end_time=_stamp(t), metadata=metadata).encode())]

    def of(self, topic: str, message: dict) -> list[tuple[str, int, bytes]]:
        """The channel messages of one telemetry message (``topic``: state, internals, ...)."""
        made = getattr(self, topic, None) if topic in ("state", "internals", "stats", "contact", "event", "model") else None
        return made(message) if made is not None else []
