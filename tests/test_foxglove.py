"""``pneumad run --foxglove HOST:PORT`` (daemon/messenger/foxglove_stream.py), through a real
Foxglove WebSocket client (daemon/testing/foxglove_client.py: the `websockets` package, the
advertised schemas decoded with `protobuf`): a JointStates channel at loop rate, the daemon's
events as Log messages, a stalled client that loses only its own messages, and the layout
(docs/foxglove-layout.json) naming only what the daemon advertises."""
import base64
import json
import math
import re
import time
from pathlib import Path

import pytest
import websockets.exceptions
import websockets.sync.client

from mcap.reader import make_reader

from daemon import recordings as recording
from daemon.client import plots
from daemon.client.client import Client
from daemon.loop.port import foxglove_address
from daemon.recordings import layout
from daemon.recordings.channels import (
    COMMANDED_PRESSURES,
    JOINT_STATES,
    LOG,
    LOOP,
    MEASURED_PRESSURES,
    TRACKING,
    Frames,
    json_schemas,
    ns,
)
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.foxglove_client import FoxgloveClient, protobuf_class
from daemon.testing.loop import dealer, make_loop, ok
from hal.errors import ConfigError
from tests.daemons import free_tcp_ports, real_daemon, wait_for_own_daemon

LAYOUT = Path(__file__).resolve().parent.parent / "docs" / "foxglove-layout.json"


@pytest.fixture(scope="module")
def fox(tmp_path_factory):
    """A daemon serving Foxglove on a free loopback port: (client over ZeroMQ, the port)."""
    (port,) = free_tcp_ports(1)
    daemon, eps = real_daemon(tmp_path_factory.mktemp("fox"), "--foxglove", f"127.0.0.1:{port}")
    try:
        with Client(**eps, timeout=10.0) as client:
            wait_for_own_daemon(client, daemon)
            yield client, port
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


def joint_states(fc: FoxgloveClient, count: int, others: list | None = None, limit_s: float = 60.0) -> list:
    """``count`` JointStates messages as (log time [ns], message); other topics' messages
    (topic, log time, message) go to ``others`` if given."""
    got, deadline = [], time.monotonic() + limit_s
    while len(got) < count and time.monotonic() < deadline:
        item = fc.receive(5.0)
        if item is not None and item[0] == JOINT_STATES:
            got.append(item[1:])
        elif item is not None and others is not None:
            others.append(item)
    assert len(got) == count, f"{len(got)} JointStates in {limit_s} s"
    return got


@pytest.mark.slow(seconds=8)
def test_joint_states_at_loop_rate_and_events_as_log(fox):
    client, port = fox
    # the Log line on a client of its own: a client taking in 1000 JointStates a second on a
    # loaded machine may fall behind, and the server drops its oldest messages (the protocol's
    # rule for a slow client), which can be the Log line itself
    fc, logs_client = FoxgloveClient(port), FoxgloveClient(port)
    try:
        channels = fc.advertised([JOINT_STATES, TRACKING, LOG])
        js = channels[JOINT_STATES]
        assert (js["schemaName"], js["encoding"], js["schemaEncoding"]) == ("foxglove.JointStates", "protobuf", "protobuf")
        assert channels[TRACKING]["encoding"] == "json" and channels[TRACKING]["schemaEncoding"] == "jsonschema"
        logs_client.advertised([LOG])
        logs_client.subscribe([LOG])
        fc.subscribe([JOINT_STATES, TRACKING])
        joint_states(fc, 1)  # the server has taken the subscriptions (those before it too)
        client.acquire_lease()
        client.keep_lease()
        client.enable()  # an event: the state change, as a Log line
        others = []
        received = joint_states(fc, 1200, others)
        client.disable()
        client.release_lease()
        logs, deadline = [], time.monotonic() + 30.0
        while not any("to=enabled" in text for text in logs) and time.monotonic() < deadline:
            item = logs_client.receive(1.0)
            if item is not None and item[0] == LOG:
                logs.append(item[2].message)
    finally:
        fc.close()
        logs_client.close()
    stamps = [t for t, _ in received]
    steps = sorted(b - a for a, b in zip(stamps, stamps[1:]))
    # one a cycle: 1 ms apart [ns] on a quiet machine; the stamps are the samples' own times, which a
    # loaded one stretches (beside two CPU hogs the median step was 1.2 ms, the loop without real-time
    # priority waking late); one a state batch would be 10 ms apart
    assert steps[0] > 0 and 0.5e6 <= steps[len(steps) // 2] <= 3e6, steps[len(steps) // 2]
    last = received[-1][1]
    assert [j.name for j in last.joints] == ["bottom", "middle"]  # the rig file's names
    assert last.timestamp.seconds * 10**9 + last.timestamp.nanos == pytest.approx(stamps[-1], abs=1)
    assert all(math.isfinite(j.position) and math.isfinite(j.effort) for j in last.joints)
    assert any("to=enabled" in text for text in logs), logs
    tracking = {t: m for topic, t, m in others if topic == TRACKING}
    at, js = next((t, m) for t, m in reversed(received) if t in tracking)
    assert tracking[at]["joints"]["middle"]["position_deg"] == pytest.approx(math.degrees(js.joints[1].position))


def test_layout_names_only_advertised_channels_and_fields(fox):
    _, port = fox
    layout = json.loads(LAYOUT.read_text())
    paths = sorted(set(message_paths(layout)))
    assert len(paths) >= 10, paths  # the plots of the layout's panels are there
    fc = FoxgloveClient(port)
    try:
        topics = {p.split(".", 1)[0] for p in paths}
        channels = fc.advertised(topics, limit_s=30.0)
    finally:
        fc.close()
    for path in paths:
        topic, _, fields = path.partition(".")
        channel = channels[topic]
        names = [re.sub(r"\[.*?\]|\{.*?\}", "", f) for f in re.split(r"\.(?![^{]*\})", fields) if f]
        if channel["encoding"] == "json":
            node = json.loads(channel["schema"])
            for name in names:
                assert name in node.get("properties", {}), f"{path}: no {name!r} in {topic}'s schema"
                node = node["properties"][name]
        else:
            node = protobuf_class(channel["schemaName"], base64.b64decode(channel["schema"])).DESCRIPTOR
            for name in names:
                assert name in node.fields_by_name, f"{path}: no {name!r} in {channel['schemaName']}"
                node = node.fields_by_name[name].message_type or node


def test_the_layout_file_is_the_built_in_rigs(capsys):
    """docs/foxglove-layout.json is what ``python -m daemon.recordings.layout`` writes."""
    assert layout.main([]) == 0
    assert json.loads(capsys.readouterr().out) == json.loads(LAYOUT.read_text())


def message_paths(value):
    """Every Foxglove message path in a layout (a string that starts with a topic and a dot)."""
    if isinstance(value, dict):
        for item in value.values():
            yield from message_paths(item)
    elif isinstance(value, list):
        for item in value:
            yield from message_paths(item)
    elif isinstance(value, str) and re.match(r"^/[\w/]+(\.|$)", value):
        yield value


@pytest.mark.slow(seconds=35)
def test_a_stalled_client_loses_only_its_own_messages(fox):
    """A client that stops reading: the loop's telemetry is all delivered (ZeroMQ subscriber,
    ring never full), a second Foxglove client keeps getting every cycle, and the stalled one,
    once it reads again, finds a gap: the server dropped its oldest messages, for it alone."""
    client, port = fox
    stalled = FoxgloveClient(port, stalled=True)
    healthy = FoxgloveClient(port)
    sub = client.subscribe((b"state",))
    try:
        stalled.subscribe(list(stalled.advertised([JOINT_STATES, TRACKING])))  # every channel: the most data
        healthy.advertised([JOINT_STATES])
        healthy.subscribe([JOINT_STATES])
        dropped_before = client.status()["telemetry"]["dropped"]
        seen = [joint_states(healthy, 1)[0][0]]
        # The stalled client's share (every channel, about 6 messages a cycle) overflows its
        # queue (20 000 messages) and the socket buffers (about 16 000 here) within 6000 cycles:
        # read the healthy client until it has seen 10 000, however long that takes here.
        while len(seen) < 10_000:
            seen.append(joint_states(healthy, 1)[0][0])
        cycles = []  # the state stream over ZeroMQ up to the healthy client's last
        while not cycles or cycles[-1] < seen[-1]:
            item = sub.receive(10.0)
            assert item is not None, "the state stream stopped"
            cycles.extend(ns(t) for t in item[1]["t"])
        stalled_seen = []  # the stalled client reads again: its old messages, a gap, the newest
        while not stalled_seen or stalled_seen[-1] < seen[-1]:
            item = stalled.receive(10.0)
            assert item is not None, "the stalled client was given nothing more"
            if item[0] == JOINT_STATES:
                stalled_seen.append(item[1])
        telemetry = client.status()["telemetry"]
    finally:
        sub.close()
        stalled.close()
        healthy.close()
    assert sub.lost == 0 and telemetry["dropped"] == dropped_before  # the loop's telemetry all went out
    assert telemetry["messenger_restarts"] == 0
    window = [c for c in cycles if max(seen[0], cycles[0]) <= c <= seen[-1]]
    assert len(window) > 1000 and set(window) <= set(seen)  # every cycle reached the healthy client
    gaps = [b - a for a, b in zip(stalled_seen, stalled_seen[1:])]
    assert stalled_seen and max(gaps) > 0.5e9, "the stalled client lost nothing: it never stalled"


@pytest.mark.slow(seconds=5)  # a few seconds: kept out of the fast subset
def test_a_recording_made_by_the_daemon_has_the_live_streams_channels_and_old_readers_read_it(fox):
    """The same topics, encodings, schema names and schemas as the live stream advertises, and
    recording.load / export / plot (which read the /pneumad/<topic> channels) still work."""
    client, port = fox
    client.record_stop() if client.record_list()["active"] else None
    started = client.record_start(name="fox", seconds=1.0)
    deadline = time.monotonic() + 60.0
    while any(a["name"] == "fox" for a in client.record_list()["active"]):
        assert time.monotonic() < deadline, "the recording did not end"
        time.sleep(0.2)
    path = Path(started["file"])
    fc = FoxgloveClient(port)
    try:
        advertised = fc.advertised([JOINT_STATES, TRACKING, LOG], limit_s=30.0)
    finally:
        fc.close()
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        recorded = {c.topic: (c, summary.schemas[c.schema_id]) for c in summary.channels.values()}
        counts = summary.statistics.channel_message_counts
        joint_states_recorded = counts[recorded[JOINT_STATES][0].id]
    for topic, ad in advertised.items():
        channel, schema = recorded[topic]
        assert (channel.message_encoding, schema.name, schema.encoding) == (ad["encoding"], ad["schemaName"],
                                                                            ad["schemaEncoding"]), topic
        data = base64.b64decode(ad["schema"]) if ad["schemaEncoding"] == "protobuf" else ad["schema"].encode()
        assert json.loads(schema.data) == json.loads(data) if ad["schemaEncoding"] == "jsonschema" else \
            schema.data == data, topic
    data = recording.load(path)
    assert joint_states_recorded == len(data["t"]) > 500  # a JointStates a cycle, as the state stream
    out = path.parent / "fox-plots"
    assert any(p.name.endswith("-joints.png") for p in plots.plot_runs([path], out))
    assert recording.export_csv(path, path.parent / "fox.csv") == len(data["t"])


@pytest.mark.slow(seconds=15)
def test_a_viewer_offering_only_the_older_subprotocol_is_refused_and_the_log_says_the_fix(tmp_path):
    """foxglove-sdk refuses foxglove.websocket.v1 (an older Foxglove, Lichtblick before 1.22.1)
    with a bare HTTP 400 and logs only "handshake failed": the daemon's log says why and what to
    use. A real client (websockets) offering only that subprotocol, a real daemon's log."""
    (port,) = free_tcp_ports(1)
    log = tmp_path / "daemon.log"
    with open(log, "w") as out:
        daemon, eps = real_daemon(tmp_path, "--foxglove", f"127.0.0.1:{port}", stderr=out)
    try:
        with Client(**eps, timeout=10.0) as client:
            wait_for_own_daemon(client, daemon)
        FoxgloveClient(port).ws.close()  # listening (the current subprotocol is served)
        with pytest.raises(websockets.exceptions.InvalidStatus) as refused:
            websockets.sync.client.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.websocket.v1"],
                                           open_timeout=30)
        assert refused.value.response.status_code == 400
        deadline = time.monotonic() + 30.0
        while "handshake failed" not in log.read_text() and time.monotonic() < deadline:
            time.sleep(0.1)
        line = next(line for line in log.read_text().splitlines() if "handshake failed" in line)
        assert "foxglove.sdk.v1" in line and "foxglove.websocket.v1" in line and "Lichtblick 1.22.1" in line
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


def test_foxglove_listens_on_loopback_unless_insecure():
    assert foxglove_address("127.0.0.1:8765", False) == ("127.0.0.1", 8765)
    with pytest.raises(ConfigError, match="ssh -L 8765:127.0.0.1:8765"):
        foxglove_address("0.0.0.0:8765", False)
    assert foxglove_address("0.0.0.0:8765", True) == ("0.0.0.0", 8765)
    with pytest.raises(ConfigError, match="HOST:PORT"):
        foxglove_address("8765", False)


def test_each_panel_says_what_its_channel_holds_commanded_and_measured_pressures_apart():
    """The commanded pressures channel holds the chamber pressure commands the loop wrote (not
    a sensor's reading): its panel and its schema say so. On a rig with chamber transmitters
    (the muscle rig) the measured pressures have a channel and panels of their own. The loop
    panel's work line is the cycle's total."""
    loop, captured, srv = make_loop(server=True)
    try:
        describe = ok(loop, dealer(srv), "describe")
        loop.enable()
        loop.run(300)
    finally:
        srv.close()
    state = captured.of("state")[-1]
    head, rod = [state[f"{j}.p_head_cmd"][-1] for j in ("bottom", "middle")], [state[f"{j}.p_rod_cmd"][-1]
                                                                               for j in ("bottom", "middle")]
    written = [state[f"out.{ch.name}"][-1] for ch in loop.io.transport.outputs]
    assert loop.io.volts_for(head, rod) == pytest.approx(written)  # the commands the regulators were sent
    frames = {topic: json.loads(data) for topic, _, data in Frames(describe).state(state, rows=[len(state["cycle"]) - 1])
              if topic != JOINT_STATES}
    assert [frames[COMMANDED_PRESSURES]["joints"][j]["p_head_cmd_kpa"] * 1e3 for j in ("bottom", "middle")] == \
        pytest.approx(head)
    assert MEASURED_PRESSURES not in frames and MEASURED_PRESSURES not in json_schemas(describe)  # no transmitter
    schema_title = json_schemas(describe)[COMMANDED_PRESSURES]["title"]
    assert "COMMANDED" in schema_title and "measured" not in schema_title.replace("not measured", "")
    panels = list(plot_panels(json.loads(layout.build(describe).to_json())))
    pressure_panels = [p for p in panels if any(s["value"].startswith("/pneumad/") and "pressures" in s["value"]
                                                for s in p["config"]["paths"])]
    assert len(pressure_panels) == 2
    for panel in pressure_panels:
        assert "pressures commanded" in panel["title"] and "measured" not in panel["title"], panel["title"]
    work = [s for p in panels for s in p["config"]["paths"] if s["value"] == f"{LOOP}.compute_us.p99"]
    assert work and "read to commands" in work[0]["label"]  # the channel's compute_us is the stats' total

    from importlib import resources
    loop, captured, srv = make_loop(resources.files("hal").joinpath("sim_muscle.toml").read_text(), server=True,
                                    controller="muscle_eq")
    try:
        describe = ok(loop, dealer(srv), "describe")
        loop.enable()
        loop.run(300)
    finally:
        srv.close()
    state = captured.of("state")[-1]
    frames = {topic: json.loads(data) for topic, _, data in Frames(describe).state(state, rows=[len(state["cycle"]) - 1])
              if topic != JOINT_STATES}
    measured, commanded = frames[MEASURED_PRESSURES]["joints"]["elbow"], frames[COMMANDED_PRESSURES]["joints"]["elbow"]
    assert set(measured) == {"p_a_kpa", "p_b_kpa"} and set(commanded) == {"p_a_cmd_kpa", "p_b_cmd_kpa"}
    assert measured["p_a_kpa"] * 1e3 == pytest.approx(state["elbow.p_a"][-1])
    assert commanded["p_a_cmd_kpa"] * 1e3 == pytest.approx(state["elbow.p_a_cmd"][-1])
    titles = [p["title"] for p in plot_panels(json.loads(layout.build(describe).to_json()))]
    assert "elbow: chamber pressures measured" in titles and any("pressures commanded" in t for t in titles)


def plot_panels(value):
    """Every plot panel of a layout (a dict with a title and a config of paths)."""
    if isinstance(value, dict):
        if "title" in value and isinstance(value.get("config"), dict) and "paths" in value["config"]:
            yield value
        for item in value.values():
            yield from plot_panels(item)
    elif isinstance(value, list):
        for item in value:
            yield from plot_panels(item)
