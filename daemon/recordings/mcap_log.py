"""Recordings as MCAP, the container Foxglove, PlotJuggler and the ROS 2 bag tools open.

One channel per telemetry topic (``/pneumad/state``, ``/pneumad/stats``, ``/pneumad/event``,
``/pneumad/internals``, ``/pneumad/contact``, ``/pneumad/model``), each message JSON-encoded against a JSON Schema (encoding
``jsonschema``, which both viewers read natively). ``state`` is written one message per
loop cycle, not per batch: its log time is the sample's time on the daemon's monotonic
clock [ns] and its sequence number the cycle, and it is the cycle's record, flat, one key per
field of the cycle layout (:mod:`daemon.wire.cycle_layout`: ``middle.position`` [rad],
``middle.p_head_cmd`` [Pa] ...; a number nobody wrote is null), its schema made from the layout
with each field's unit, so a viewer plots them by name. Lost telemetry (a gap in
a topic's ``seq``) is written where it happened, on ``/pneumad/gap``. The rig file is an
attachment; ``describe`` (with the ``cycle_layout``), the controller and its parameters, the
software version and the rig hash are metadata records. Recordings made before the layout
(nested samples) read into the same flat samples (:mod:`daemon.recordings.legacy`).

Beside them, the Foxglove channels of the live stream (:mod:`daemon.recordings.channels`:
``/joint_states``, ``/pneumad/tracking`` ..., ``/log``, ``/events``), with the same schemas, so
one Foxglove layout (docs/foxglove-layout.json) serves live and recorded data; :func:`read`
(and so ``recording.load``, ``export``, ``plot``) reads the ``/pneumad/<topic>`` channels
alone, in files with or without them.

Chunks are closed every CHUNK_BYTES, so a recording cut short (a killed recorder, a full
disk) loses at most its last chunk: :func:`read` returns everything up to it and says the file
is cut, and :func:`daemon.recordings.mcap_repair.repair` finishes such a file for every other
reader. How long a recording was meant to run is in its ``pneumad`` metadata
(``planned_s``, ``planned_end_t``), so a reader of a cut one can say how much is missing.
"""
from __future__ import annotations

import json
import math
import signal
import struct
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

from mcap.exceptions import McapError
from mcap.records import Attachment, Channel, DataEnd, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import Writer

from daemon.recordings.channels import Frames, json_bytes, json_schemas, ns, protobuf_schemas, schema_name
from daemon.recordings.legacy import Converter, layout_of
from daemon.recordings.mcap_repair import CUT
from daemon.wire.cycle_layout import MODES, CycleLayout

PROFILE = ""  # no ROS profile: plain JSON messages
CHUNK_BYTES = 256 * 1024  # about half a second of state at 1 kHz
HEARD_LIMIT_S = 5.0  # record() waits this long at most for its subscription to be heard [s]
TOPICS = ("state", "stats", "event", "internals", "contact", "model", "gap")
NAN = float("nan")


def channel(topic: str) -> str:
    return f"/pneumad/{topic}"


def state_schema(layout: CycleLayout) -> dict:
    """The ``/pneumad/state`` schema: one property per field of the layout, with its unit."""
    def prop(f) -> dict:
        kind = {"cycle": "integer", "mode": "string"}.get(f.name, ["number", "null"])  # null: nobody wrote it
        extra = {"enum": list(MODES)} if f.name == "mode" else {}
        return {"type": kind, "description": f"{f.group}, {f.unit}", **extra}
    return {"title": "pneumad state sample: one loop cycle's record (SI units, volts at the hardware edge)",
            "type": "object", "properties": {f.name: prop(f) for f in layout.fields}}


OTHER_SCHEMAS = {
    "stats": {"title": "pneumad loop timing, once a stats period (docs/protocol.md)", "type": "object"},
    "event": {"title": "pneumad event: state change, trip, switch ... (docs/protocol.md)", "type": "object",
              "properties": {"kind": {"type": "string"}, "cause": {"type": "string"}}},
    "internals": {"title": "the active controller's internal signals, per joint", "type": "object",
                  "properties": {"controller": {"type": "string"}, "signals": {"type": "object"}}},
    "contact": {"title": "the array pressure sensor's latest contact estimate (docs/protocol.md)", "type": "object",
                "properties": {"frame": {"type": "integer"}, "frame_t": {"type": "number"}, "age_s": {"type": ["number", "null"]},
                               "contact": {"type": ["object", "null"]}}},
    "model": {"title": "the model beside the arm: each joint's residual [deg] since the last message and its window's "
                       "statistics (docs/model.md)", "type": "object",
              "properties": {"t": {"type": "number"}, "first_cycle": {"type": ["integer", "null"]},
                             "band_deg": {"type": "number"}, "joints": {"type": "object"}}},
    "gap": {"title": "telemetry lost between two messages of a topic", "type": "object",
            "properties": {"topic": {"type": "string"}, "missing": {"type": "integer"}, "after_seq": {"type": ["integer", "null"]}}},
}


def state_samples(layout: CycleLayout, m: dict) -> Iterator[dict]:
    """A ``state`` message (columns, as published) as one flat sample per cycle, keyed by the
    layout's field names: what a recording holds and what its readers return."""
    columns = [(name, m[name]) for name in layout.names]
    for i in range(len(m["cycle"])):
        yield {name: values[i] for name, values in columns}


class TelemetryEncoder:
    """One daemon's telemetry as the messages of a recording's channels (``/pneumad/<topic>`` and
    the Foxglove channels beside them): encoded once, whatever the number of recordings that
    write them (the recorder's several recordings share one: the encoding is most of a
    recording's cost). It follows the events it encodes (a reference's phase), so it sees every
    message once."""

    def __init__(self, describe: dict):
        self.layout = layout_of(describe)
        self._frames = Frames(describe)  # the Foxglove channels, as the live stream serves them
        self._last_t = 0.0

    def encode(self, topic: str, message: dict) -> list[tuple[str, int, bytes, int]]:
        """One telemetry message as (channel, log time [ns], data, sequence) records; none for a
        topic a recording does not keep."""
        if topic not in TOPICS:
            return []
        out = [(name, stamp, data, 0) for name, stamp, data in self._frames.of(topic, message)]
        if topic == "state":
            for row in state_samples(self.layout, message):
                out.append((STATE_CHANNEL, ns(row["t"]), json_bytes(row), row["cycle"]))
                self._last_t = row["t"]
        else:
            self._last_t = message.get("t", self._last_t)
            out.append((channel(topic), ns(self._last_t), json_bytes(message), 0))
        return out


STATE_CHANNEL = channel("state")


class McapRecording:
    """Writes telemetry as the daemon publishes it (decoded messages, as a subscriber sees
    them) to an open binary file: encoded by ``encoder`` (shared between recordings of one
    daemon; default: its own). ``plan``: how long it is meant to run, as far as known when it
    starts: ``planned_s`` [s] from its first sample and/or ``planned_end_t`` [s] on the daemon's
    clock (metadata a reader of a cut file says how much is missing by)."""

    def __init__(self, f, describe: dict, controller: dict, encoder: TelemetryEncoder | None = None,
                 plan: dict[str, float] | None = None):
        self.encoder = encoder or TelemetryEncoder(describe)
        self._writer = Writer(f, chunk_size=CHUNK_BYTES)
        self._writer.start(PROFILE, f"pneumad {describe.get('version', '?')}")
        self._ids: dict[str, int] = {}  # channel -> its id in this file
        for topic in TOPICS:
            schema = state_schema(self.encoder.layout) if topic == "state" else OTHER_SCHEMAS[topic]
            sid = self._writer.register_schema(f"pneumad.{topic}", "jsonschema", json.dumps(schema).encode())
            self._ids[channel(topic)] = self._writer.register_channel(channel(topic), "json", sid)
        self._ours = set(self._ids)
        for topic, schema in json_schemas(describe).items():
            sid = self._writer.register_schema(schema_name(topic), "jsonschema", json.dumps(schema).encode())
            self._ids[topic] = self._writer.register_channel(topic, "json", sid)
        for topic, (name, data) in protobuf_schemas().items():
            sid = self._writer.register_schema(name, "protobuf", data)
            self._ids[topic] = self._writer.register_channel(topic, "protobuf", sid)
        now = time.time_ns()
        self._writer.add_attachment(now, now, "rig.toml", "application/toml", describe["rig"]["source"].encode())
        self._writer.add_metadata("pneumad", {"software": str(describe.get("version")), "rig_hash": describe["rig"]["hash"],
                                              "rig_name": describe["rig"]["name"], "controller": controller["name"],
                                              "started_unix_s": f"{now / 1e9:.3f}",
                                              **{k: repr(float(v)) for k, v in (plan or {}).items()}})
        self._writer.add_metadata("describe", {"json": json.dumps(describe)})
        self._writer.add_metadata("controller", {"json": json.dumps(controller)})
        self._last_seq: dict[str, int] = {}
        self._last_stamp = 0  # [ns] of the last message written
        self.messages = 0  # on the /pneumad channels
        self.gaps = 0

    def write(self, topic: str, message: dict, lost: int = 0,
              encoded: list[tuple[str, int, bytes, int]] | None = None) -> None:
        """One telemetry message (``encoded``: what this recording's encoder made of it, if it
        has been encoded already); ``lost`` messages of this topic went missing before it."""
        if topic not in TOPICS:
            return
        seq = message.get("seq")
        if lost or (seq is not None and topic in self._last_seq and seq > self._last_seq[topic] + 1):
            missing = lost or seq - self._last_seq[topic] - 1
            self.gaps += missing
            gap = {"topic": topic, "missing": missing, "after_seq": self._last_seq.get(topic)}
            self._add(channel("gap"), self._last_stamp, json_bytes(gap), 0)
        if seq is not None:
            self._last_seq[topic] = seq
        for name, stamp, data, sequence in self.encoder.encode(topic, message) if encoded is None else encoded:
            self._add(name, stamp, data, sequence)

    def _add(self, name: str, stamp: int, data: bytes, sequence: int) -> None:
        self._writer.add_message(self._ids[name], stamp, data, stamp, sequence)
        self._last_stamp = stamp
        if name in self._ours:
            self.messages += 1

    def finish(self) -> None:
        self._writer.finish()


def record(client, path, seconds: float, progress=None, stop=None, started=None) -> tuple[int, int]:
    """Record a daemon's telemetry for ``seconds`` (or until the event ``stop`` is set) through
    ``client`` (a :class:`daemon.client.client.Client`) to ``path``; (messages, messages lost). An
    OSError (a full disk) propagates, the file readable up to its last complete chunk (and
    finished so by :func:`daemon.recordings.mcap_repair.repair`).
    ``progress(elapsed_s, messages, lost)`` is called after every message or idle half second.
    The recording starts once the daemon's publisher has the subscription (the first ``stats``
    message: :meth:`Subscription.wait_until_heard`, at most ``HEARD_LIMIT_S``); the event
    ``started`` is then set, for a caller that sends what is to be recorded from another thread.
    Ctrl-C ends it early with the file finished, then raises KeyboardInterrupt: in the main
    thread it is taken between two messages (within half a second), never inside a record's
    bytes, which would leave a chunk that cannot be read."""
    describe, controller = client.describe(), client.controller()
    sub = client.subscribe((b"state", b"stats", b"event", b"internals", b"contact"))
    try:
        sub.wait_until_heard(HEARD_LIMIT_S)
    except TimeoutError:  # a loop stalled publishes no stats: what comes is recorded, from when it comes
        pass
    if started is not None:
        started.set()
    interrupted = threading.Event()
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, lambda *_: interrupted.set()) if in_main else None
    try:
        with open(path, "wb") as f:
            rec = McapRecording(f, describe, controller, plan={"planned_s": seconds} if math.isfinite(seconds) else None)
            start = time.monotonic()
            while time.monotonic() < start + seconds and not (stop is not None and stop.is_set()) \
                    and not interrupted.is_set():
                item = sub.receive(0.5)
                if item is not None:
                    rec.write(*item)
                if progress is not None:
                    progress(time.monotonic() - start, rec.messages, sub.lost)
            rec.finish()
    finally:
        if in_main:
            signal.signal(signal.SIGINT, previous)
        sub.close()
    if interrupted.is_set():
        raise KeyboardInterrupt
    return rec.messages, sub.lost


@dataclass
class Contents:
    """What :func:`read` found: messages per topic in file order, attachments, metadata, and
    whether the file ended early (a recording cut short: ``truncated`` says how, "" if not)."""

    messages: dict[str, list[dict]] = field(default_factory=lambda: {t: [] for t in TOPICS})
    attachments: dict[str, bytes] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: str = ""

    @property
    def describe(self) -> dict:
        return json.loads(self.metadata["describe"]["json"])

    @property
    def controller(self) -> dict:
        return json.loads(self.metadata["controller"]["json"])

    @property
    def layout(self) -> CycleLayout:
        """The state samples' fields (the describe's ``cycle_layout``, or the one it implies)."""
        return layout_of(self.describe)

    @property
    def plan(self) -> dict[str, float]:
        """How long the recording was meant to run (``planned_s``, ``planned_end_t``), where it says."""
        pneumad = self.metadata.get("pneumad", {})
        return {k: float(pneumad[k]) for k in ("planned_s", "planned_end_t") if k in pneumad}


def _null_to_nan(sample: dict) -> None:
    """A state sample as written (a number nobody wrote is null, as JSON has no NaN) back to
    what its readers take: NaN for each such number (in a nested one, made before the layout,
    its groups' numbers)."""
    for key, value in sample.items():
        if value is None:
            sample[key] = NAN
        elif isinstance(value, dict):
            _null_to_nan(value)


def read(path) -> Contents:
    """Everything in a pneumad MCAP recording, up to its last complete record: a truncated
    file yields what was written before the cut, with ``truncated`` saying so, as does a cut file
    finished afterwards (:mod:`daemon.recordings.mcap_repair`)."""
    out = Contents()
    ours = {channel(t): t for t in TOPICS}  # the Foxglove channels beside them are the viewers'
    topics: dict[int, str] = {}
    data_whole = False  # its data end came: whatever is cut after it is the index alone
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f).records:
                if isinstance(record, Channel):
                    if record.topic in ours:
                        topics[record.id] = ours[record.topic]
                elif isinstance(record, Message) and record.channel_id in topics:
                    topic = topics[record.channel_id]
                    message = json.loads(record.data)
                    if topic == "state" and b"null" in record.data:
                        _null_to_nan(message)
                    out.messages.setdefault(topic, []).append(message)
                elif isinstance(record, Attachment):
                    out.attachments[record.name] = record.data
                elif isinstance(record, Metadata):
                    out.metadata[record.name] = dict(record.metadata)
                elif isinstance(record, DataEnd):
                    data_whole = True
        except (McapError, EOFError, ValueError, struct.error):  # cut short: keep what came before
            out.truncated = ("no footer: the index after its data is cut; no message is missing" if data_whole else
                             "no footer or index: the file ends inside a record")
    if CUT in out.metadata and not out.truncated:
        cut = out.metadata[CUT]
        out.truncated = (f"{cut.get('cause', 'cut')}; closed at its last complete chunk on "
                         f"{time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(float(cut.get('repaired_unix_s', 0))))}")
    if "describe" not in out.metadata:
        raise ValueError(f"{path}: not a pneumad MCAP recording (no describe metadata{': ' + out.truncated if out.truncated else ''})")
    states = out.messages["state"]
    if states and "joints" in states[0]:  # nested: made before the cycle layout
        convert = Converter(out.describe).nested
        out.messages["state"] = [convert(s) for s in states]
    return out
