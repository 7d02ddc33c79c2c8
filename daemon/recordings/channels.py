"""The Foxglove channels: one set of topics and schemas for the live stream
(``pneumad run --foxglove``, :mod:`daemon.messenger.foxglove_stream`) and the recordings
(:mod:`daemon.recordings.mcap_log` writes them beside its ``/pneumad/<topic>`` channels), so
one layout (docs/foxglove-layout.json) serves live and recorded data.

From the telemetry as subscribers see it (``state`` columns, ``internals``, ``stats``,
``event``, ``contact``), :class:`Frames` makes (topic, log time [ns], encoded message):

- ``/joint_states``: ``foxglove.JointStates`` (protobuf), one per loop cycle: per joint (named
  as the rig file names it) position [rad], velocity [rad/s] and effort, the commanded chamber
  pressure difference head - rod (a muscle pair's a - b) [Pa]: the torque needs a moment arm and areas
  the daemon does not publish, the pressure difference is what drives the joint.
- JSON-schema channels, one message per cycle: ``/pneumad/tracking`` (angle, set-point, error,
  velocity [deg, deg/s], the loop's mode and the reference's phase: approach, settle, path or hold),
  ``/pneumad/commands`` (each command interface in force with its limits: V_MV [V], a muscle
  pair's pressures [Pa], brake [N m]; the output volts actually written; ``output`` says
  ``safe state`` whenever the safe state is written instead of the controller's output),
  ``/pneumad/pressures`` (the head and rod chambers' pressure commands [kPa], as written), ``/pneumad/tip`` (forward kinematics of
  the first two joints [mm], measured and set-point);
  and one per message: ``/pneumad/controller`` (the internals, each signal's unit from the
  controller that published it), ``/pneumad/loop`` (timing), ``/pneumad/contact_estimate``.
- ``/log`` (``foxglove.Log``) and ``/events`` (``foxglove.Event``) for the daemon's events:
  trips, switches, references starting and ending (an ending's event spans the reference).

Log times are the daemon's monotonic clock [ns], as the recordings' other channels.
"""
from __future__ import annotations

import json
import math

import orjson
from foxglove.messages import Event, JointState, JointStates, KeyValuePair, Log, LogLevel, Timestamp

JOINT_STATES, LOG, EVENTS = "/joint_states", "/log", "/events"
TRACKING, COMMANDS, PRESSURES, TIP = "/pneumad/tracking", "/pneumad/commands", "/pneumad/pressures", "/pneumad/tip"
CONTROLLER, LOOP, CONTACT = "/pneumad/controller", "/pneumad/loop", "/pneumad/contact_estimate"
SAFE_STATE = "safe state"
ERRORS = ("trip", "estop", "loop_stalled")  # event kinds logged as errors; warnings below
WARNINGS = ("tracking", "experiment", "unleased", "lease_revoked", "messenger", "recorder", "recover")
_PROTOBUF = {JOINT_STATES: JointStates, LOG: Log, EVENTS: Event}

_NUMBER = {"type": ["number", "null"]}  # null: not finite, or not measured (json_bytes)
_TIME = {"type": "number"}  # [s] on the daemon's clock


def _obj(properties: dict, title: str = "") -> dict:
    schema = {"type": "object", "properties": properties}
    return {"title": title, **schema} if title else schema


def _numbers(*names: str) -> dict:
    return _obj({n: _NUMBER for n in names})


def json_schemas(describe: dict) -> dict[str, dict]:
    """Each JSON channel's schema for this daemon's rig (joints by name, its command interfaces)."""
    joints = [j["name"] for j in describe["joints"]]
    per_joint = lambda fields: _obj({j: fields(j) for j in joints})  # noqa: E731
    commands = {j: [c["name"] for c in describe.get("command_interfaces", []) if c["joint"] == j] for j in joints}
    stamp = {"t": _TIME, "cycle": {"type": "integer"}}
    figures = _numbers("p50", "p99", "p99.9", "max")
    return {
        TRACKING: _obj({**stamp, "mode": {"type": "string"}, "phase": {"type": "string"},
                        "joints": per_joint(lambda j: _numbers("angle_deg", "setpoint_deg", "error_deg",
                                                               "velocity_deg_s"))},
                       "set-points and tracking errors per joint [deg]; the loop's mode, the reference's phase"),
        COMMANDS: _obj({**stamp, "output": {"type": "string"},
                        "joints": per_joint(lambda j: _numbers(*(f"{c}{s}" for c in commands[j]
                                                                 for s in ("", "_min", "_max")))),
                        "written_volts": _obj({o[0]: _NUMBER for o in describe["transport"]["outputs"]})},
                       "command interfaces in force and their limits (V_MV [V], pressures [Pa], brake [N m]); "
                       "output volts written; output: controller or safe state"),
        PRESSURES: _obj({**stamp, "joints": per_joint(lambda j: _numbers("p_head_kpa", "p_rod_kpa"))},
                        "chamber pressure commands [kPa], after the rig's limits (a muscle pair: a, b); "
                        "not measured pressures"),
        TIP: _obj({**stamp, **_numbers("x_mm", "y_mm", "setpoint_x_mm", "setpoint_y_mm")["properties"]},
                  "tip position by forward kinematics of the first two joints [mm]"),
        CONTROLLER: _obj({**stamp, "controller": {"type": "string"},
                          "signals": _obj({}), "units": _obj({})},
                         "the active controller's internal signals per joint, units from that controller"),
        LOOP: _obj({"t": _TIME, "cycles": {"type": "integer"}, "overruns": {"type": "integer"},
                    "latency_us": figures, "compute_us": figures}, "loop timing over a stats window [us]"),
        CONTACT: _obj({"t": _TIME, "frame": {"type": "integer"}, "age_s": _NUMBER,
                       "contact": {"type": ["object", "null"]}}, "the array sensor's contact estimate"),
    }


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
    and the standard encoder was half a recording's cost (docs/benchmarks.md, "A recording's
    JSON through orjson"). What orjson refuses (a key that is not a string, an integer past
    64 bits) goes the standard way."""
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
        self.joints = [j["name"] for j in describe["joints"]]
        self.outputs = [o[0] for o in describe["transport"]["outputs"]]
        interfaces = describe.get("command_interfaces") or [
            {"joint": j["name"], "name": "v_mv", "low": j.get("u_min_volts"), "high": j.get("u_max_volts")}
            for j in describe["joints"]]
        self._commands = [(c["joint"], c["name"], k, c.get("low"), c.get("high")) for k, c in enumerate(interfaces)]
        lengths = describe.get("arm", {}).get("link_lengths_mm", [])
        self._links = lengths[:2] if len(lengths) >= 2 and len(self.joints) >= 2 else None
        self._reference: tuple[float, float, float] | None = None  # start, approach end, end [s]
        self._settling = False  # a path's approach has ended and its clock has not started (its `settled` event)
        self._started: dict[int, float] = {}  # reference generation -> start [s]

    def state(self, m: dict, wanted=None, rows=None) -> list[tuple[str, int, bytes]]:
        """Per cycle of a ``state`` batch: joint states, tracking, commands, pressures, tip
        (``wanted``: only these topics, e.g. those a client subscribed to; None: all; ``rows``:
        only these cycles of the batch, by index; None: all)."""
        makers = [(topic, make) for topic, make in ((JOINT_STATES, self._joint_states), (TRACKING, self._tracking),
                                                   (COMMANDS, self._commands_in_force), (PRESSURES, self._pressures),
                                                   (TIP, self._tip_position))
                  if wanted is None or topic in wanted]
        out = []
        for i in range(len(m["cycle"])) if rows is None else rows:
            stamp = ns(m["t"][i])
            for topic, make in makers:
                data = make(m, i)
                if data is not None:
                    out.append((topic, stamp, data))
        return out

    def _joint_states(self, m: dict, i: int) -> bytes:
        q, w, ph, pr = m["angle_rad"][i], m["velocity_rad_s"][i], m["p_head_pa"][i], m["p_rod_pa"][i]
        return JointStates(timestamp=_stamp(m["t"][i]), joints=[
            JointState(name=name, position=q[j], velocity=w[j], effort=ph[j] - pr[j])
            for j, name in enumerate(self.joints)]).encode()

    def _tracking(self, m: dict, i: int) -> bytes:
        t, q, r, w = m["t"][i], m["angle_rad"][i], m["setpoint_rad"][i], m["velocity_rad_s"][i]
        return json_bytes({"t": t, "cycle": m["cycle"][i], "mode": m["mode"][i], "phase": self._phase(t),
                           "joints": {name: {"angle_deg": math.degrees(q[j]), "setpoint_deg": math.degrees(r[j]),
                                             "error_deg": math.degrees(r[j] - q[j]),
                                             "velocity_deg_s": math.degrees(w[j])}
                                      for j, name in enumerate(self.joints)}})

    def _commands_in_force(self, m: dict, i: int) -> bytes:
        safe, u = m["mode"][i] != "enabled", m["u_volts"][i]  # outside enabled the safe state is written
        joints: dict[str, dict] = {name: {} for name in self.joints}
        for joint, name, k, low, high in self._commands:
            joints[joint].update({name: None if safe else u[k], f"{name}_min": low, f"{name}_max": high})
        return json_bytes({"t": m["t"][i], "cycle": m["cycle"][i], "output": SAFE_STATE if safe else "controller",
                           "joints": joints, "written_volts": dict(zip(self.outputs, m["out_volts"][i]))})

    def _pressures(self, m: dict, i: int) -> bytes:
        ph, pr = m["p_head_pa"][i], m["p_rod_pa"][i]
        return json_bytes({"t": m["t"][i], "cycle": m["cycle"][i], "joints": {
            name: {"p_head_kpa": ph[j] / 1e3, "p_rod_kpa": pr[j] / 1e3} for j, name in enumerate(self.joints)}})

    def _tip_position(self, m: dict, i: int) -> bytes | None:
        if self._links is None:
            return None
        (x, y), (sx, sy) = self._tip(m["angle_rad"][i]), self._tip(m["setpoint_rad"][i])
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
        made = getattr(self, topic, None) if topic in ("state", "internals", "stats", "contact", "event") else None
        return made(message) if made is not None else []
