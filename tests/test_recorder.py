"""The daemon's own recordings (daemon/recorder/process.py, daemon/recorder/archive.py), against a real daemon:
a recorded path loses nothing while a client is stalled, record.start/stop/list answer as
documented, and a write error, a full disk or a killed recorder end a recording with an event,
the file readable, the loop untouched. (The archive alone, in this process:
tests/test_recorder_archive.py.)"""
import json
import os
import re
import resource
import signal
import time

import msgpack
import pytest
import zmq
from mcap.reader import make_reader

from bench.common import child_process
from daemon.recorder.archive import LEFT_CAUSE
from daemon.recordings import mcap_log, reading as recording
from daemon.client.client import Client, RemoteError
from daemon.testing.daemons import STOP_WAIT_S
from tests.daemons import real_daemon, wait_for_own_daemon
from tests.schemas import schema

pytestmark = pytest.mark.slow


def start(tmp_path, *options):
    """A daemon whose log (its stderr) is ``tmp_path/daemon.log``."""
    tmp_path.mkdir(exist_ok=True)
    with open(tmp_path / "daemon.log", "w") as log:
        daemon, eps = real_daemon(tmp_path, *options, stderr=log)
    daemon.log = tmp_path / "daemon.log"
    client = Client(**eps, timeout=5.0)
    wait_for_own_daemon(client, daemon)
    return daemon, eps, client


def stop(daemon, client):
    client.close()
    daemon.terminate()
    daemon.wait(STOP_WAIT_S)


@pytest.fixture(scope="module")
def shared(tmp_path_factory):
    """One daemon for the tests that leave it as they found it (a recording they started has
    ended, a recorder they killed has been replaced): a daemon start spared each."""
    daemon, eps, client = start(tmp_path_factory.mktemp("shared"))
    client.close()
    yield daemon, eps
    daemon.terminate()
    daemon.wait(STOP_WAIT_S)


@pytest.fixture
def daemon(shared):
    """The shared daemon, with a client of the test's own."""
    daemon, eps = shared
    with Client(**eps, timeout=5.0) as client:
        yield daemon, eps, client


def recorder_pid(daemon) -> int:
    """The daemon's recorder process."""
    pid = child_process(daemon.pid, "daemon.recorder.process")
    assert pid is not None, "no recorder process"
    return pid


def events(eps) -> zmq.Socket:
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"event")
    sub.connect(eps["telemetry"])
    time.sleep(0.3)  # the subscription reaches the publisher
    return sub


def wait_event(sub, match, timeout=20.0) -> dict:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if sub.poll(200):
            event = msgpack.unpackb(sub.recv_multipart()[1], raw=False)
            schema("telemetry", "event").validate(event)
            if match(event):
                return event
    raise AssertionError("the event never came")


def finished(client, name, timeout=40.0) -> str:
    """The file of recording ``name`` once it has ended."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        listing = client.record_list()
        if not any(a["name"] == name for a in listing["active"]) and any(f["name"] == name for f in listing["files"]):
            return os.path.join(listing["directory"], name + ".mcap")
        time.sleep(0.2)
    raise AssertionError(f"{name} never ended")


def holding(path, states: int, timeout=30.0) -> None:
    """Wait until the recording being written at ``path`` holds more than ``states`` state
    samples in its complete chunks."""
    end = time.monotonic() + timeout
    while True:
        try:
            if len(mcap_log.read(path).messages.get("state", [])) > states:
                return
        except (OSError, ValueError):  # not there yet, or its first chunk not yet written
            pass
        assert time.monotonic() < end, f"{path} never held {states} states"
        time.sleep(0.1)


@pytest.mark.slow(seconds=35)
def test_a_recorded_path_loses_nothing_while_a_client_is_stalled(tmp_path):
    daemon, eps, client = start(tmp_path)
    stalled = zmq.Context.instance().socket(zmq.SUB)  # subscribed, and never reads until the end
    stalled.setsockopt(zmq.LINGER, 0)
    stalled.setsockopt(zmq.RCVHWM, 10)
    stalled.setsockopt(zmq.SUBSCRIBE, b"state")
    stalled.connect(eps["telemetry"])
    try:
        client.acquire_lease(ttl_s=60.0)
        client.keep_lease()
        client.enable()
        reply = client.path("translation", record=True)
        schema("results", "path").validate(reply)
        path = finished(client, reply["recording"], timeout=reply["total_s"] + 30.0)
        status = client.status()
        assert status["state"] == "enabled" and status["trips"] == 0, status["cause"]
    finally:
        stop(daemon, client)
    contents = mcap_log.read(path)
    assert not contents.truncated
    cycles = [m["cycle"] for m in contents.messages["state"]]
    assert all(b - a == 1 for a, b in zip(cycles, cycles[1:])), "a cycle is missing from the recording"
    assert contents.messages["gap"] == []
    # It holds the whole reference, from its start to its end event, and the settling after it:
    # the recorder runs on TAIL_S (3 s) of its own wall time past the end; at least half a
    # second of cycles however busy the machine (a loaded loop skips cycles, by design).
    kinds = [(e["kind"], e.get("action")) for e in contents.messages["event"]]
    assert ("reference", "start") in kinds and ("reference", "end") in kinds
    end, = [e["cycle"] for e in contents.messages["event"] if (e["kind"], e.get("action")) == ("reference", "end")]
    assert cycles[0] <= reply["cycle"] + 1 and cycles[-1] >= end + 500, (cycles[0], reply["cycle"], end, cycles[-1])
    assert contents.controller["name"] == "pid" and contents.describe["rig"]["name"] == "sim-2joint"
    # The stalled client did lose: the recording did not depend on it.
    seqs = []
    while stalled.poll(100):
        seqs.append(msgpack.unpackb(stalled.recv_multipart()[1], raw=False)["seq"])
    stalled.close()
    # (ZeroMQ queued it ~1000 batches, then dropped the rest: the path's ~2700 batches did not fit.)
    assert len(seqs) < len(cycles) // 10 - 1000, "the stalled client lost nothing: it was not stalled"
    # The mcap package's own reader opens it, schemas and the rig file included.
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        assert {"/pneumad/state", "/pneumad/event", "/pneumad/gap"} <= set(topics)
        assert {s.encoding for t, s in topics.items() if t.startswith("/pneumad/")} == {"jsonschema"}
        assert topics["/joint_states"].name == "foxglove.JointStates"  # and the live stream's channels beside them
        assert [a.name for a in reader.iter_attachments()] == ["rig.toml"]


def test_a_daemon_without_a_recording_directory_or_disk_says_so(tmp_path):
    options = {"a": ("--record-dir", "none"), "b": ("--record-min-free-mb", "1e12")}  # b: more than any disk has
    for name in options:
        (tmp_path / name).mkdir()
    daemons = {name: real_daemon(tmp_path / name, *o) for name, o in options.items()}  # started side by side
    clients = {name: Client(**eps, timeout=5.0) for name, (_, eps) in daemons.items()}
    try:
        for name, (daemon, _) in daemons.items():
            wait_for_own_daemon(clients[name], daemon)
        with pytest.raises(RemoteError) as err:
            clients["a"].record_start()
        assert err.value.code == "bad_state" and err.value.data["reason"] == "no_recorder"
        with pytest.raises(RemoteError) as err:
            clients["b"].record_start()
        assert err.value.code == "bad_state" and "nearly full" in str(err.value)
    finally:
        for name, (daemon, _) in daemons.items():
            stop(daemon, clients[name])


def test_a_write_error_ends_the_recording_with_an_event_and_the_loop_runs_on(tmp_path):
    daemon, eps, client = start(tmp_path)
    sub = events(eps)
    try:
        client.acquire_lease(ttl_s=60.0)
        client.keep_lease()
        client.enable()
        started = client.record_start("limited")
        time.sleep(0.5)
        # The file may grow by 300 kB more, then every write fails (EFBIG, as a full disk's ENOSPC).
        limit = os.path.getsize(started["file"]) + 300_000
        resource.prlimit(recorder_pid(daemon), resource.RLIMIT_FSIZE, (limit, limit))
        failed = wait_event(sub, lambda e: e["kind"] == "record" and e["action"] == "failed")
        assert failed["name"] == "limited" and "write error" in failed["cause"] and "large" in failed["cause"]
        assert "finished up to its last complete chunk" in failed["cause"], failed["cause"]
        contents = mcap_log.read(started["file"])  # readable up to its last complete chunk
        assert len(contents.messages["state"]) > 100 and contents.truncated.startswith("write error")
        with open(started["file"], "rb") as f:  # by the mcap package's default reader too
            assert sum(1 for _ in make_reader(f).iter_messages(topics=["/pneumad/state"])) == len(contents.messages["state"])
        assert client.record_list()["active"] == []
        status = client.status()
        assert status["state"] == "enabled" and status["trips"] == 0, status["cause"]
    finally:
        sub.close()
        stop(daemon, client)


def test_record_start_stop_list_as_documented_and_refusals(daemon):
    _, _, client = daemon
    started = client.record_start("by-hand")
    schema("results", "record.start").validate(started)
    again = client.record_start("by-hand", seconds=5.0)  # the name is taken: a suffix, said in the reply
    assert again["name"] == "by-hand-2"
    listing = client.record_list()  # (5 s: a busy machine's listing came after a 0.5 s one had ended)
    schema("results", "record.list").validate(listing)
    assert {a["name"] for a in listing["active"]} == {"by-hand", "by-hand-2"}
    finished(client, "by-hand-2")  # it ends by its own limit
    stopped = client.record_stop()  # the one still running by request
    schema("results", "record.stop").validate(stopped)
    assert stopped["name"] == "by-hand" and stopped["messages"] > 50 and stopped["gaps"] == 0
    assert "record.stop" in stopped["cause"]
    files = {f["name"] for f in client.record_list()["files"]}
    assert {"by-hand", "by-hand-2"} <= files
    assert len(mcap_log.read(stopped["file"]).messages["state"]) > 500
    for args, code, words in (({}, "bad_state", "no recording started by record.start"),
                              ({"name": "nope"}, "bad_state", "no recording named")):
        with pytest.raises(RemoteError) as err:
            client.call("record.stop", args)
        assert err.value.code == code and words in str(err.value)
    with pytest.raises(RemoteError) as err:  # not a name at all: the catalog's argument check says so
        client.call("record.stop", {"name": 7})
    assert err.value.code == "bad_args" and err.value.data["argument"] == "name", err.value
    for args, argument in (({"name": "../x"}, "name"), ({"name": ""}, "name"), ({"seconds": -1}, "seconds"),
                           ({"seconds": float("nan")}, "seconds"), ({"colour": 1}, "colour")):
        with pytest.raises(RemoteError) as err:
            client.call("record.start", args)
        assert err.value.code == "bad_args" and err.value.data["argument"] == argument, err.value
    assert not os.path.exists(os.path.join(os.path.dirname(listing["directory"]), "x.mcap"))
    assert client.status()["trips"] == 0


def test_a_stopped_recording_holds_what_was_published_before_the_stop_also_from_a_recorder_behind(daemon):
    """The recorder reads its feed in batches, and a request first takes in what was published
    before it (up to the request's mark, which the messenger puts on the feed before passing the
    request on; at most 1 s of catching up): a stop cuts the file where the daemon was when it
    was sent, even from a recorder that had fallen behind (here held still for a second, as a
    loaded PC holds it), not where the recorder had got to. The messenger hands a message to
    the recorder as it publishes it, before it takes the next request: a batch this subscriber
    has received is one the recorder was given before the stop. On a machine so loaded that a
    second's backlog takes the recorder longer than its second of catching up, the file ends
    early, and the stop's cause says so, by at least what the file misses: never in silence."""
    daemon, eps, client = daemon
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"state")
    sub.connect(eps["telemetry"])
    recorder = recorder_pid(daemon)
    try:
        started = client.record_start("up-to-the-stop")
        holding(started["file"], 100)
        os.kill(recorder, signal.SIGSTOP)
        try:
            time.sleep(1.0)  # a second of telemetry queues in its feed
            while sub.poll(0):  # what queued here meanwhile: the next batch is a fresh one
                sub.recv_multipart()
            assert sub.poll(5000), "no state batch came"
            published = msgpack.unpackb(sub.recv_multipart()[1], raw=False)["t"][-1]  # [s] the daemon's clock
        finally:
            os.kill(recorder, signal.SIGCONT)
        stopped = client.record_stop(started["name"])
    finally:
        sub.close()
    recorded = mcap_log.read(stopped["file"]).messages["state"][-1]["t"]
    assert stopped["gaps"] == 0
    if "had not caught up" not in stopped["cause"]:  # the usual case: all of it, and nothing to say
        assert recorded >= published, (recorded, published)
    else:  # "... the file ends about X s before the stop", which came after `published`
        said = float(stopped["cause"].split("the file ends about ")[1].split(" s before")[0])
        assert said + 0.01 >= published - recorded > 0.0, (stopped["cause"], recorded, published)


def test_a_killed_recorder_leaves_a_file_every_reader_opens_and_another_is_started(daemon):
    """SIGKILL leaves the file without its footer; the recorder started after it finishes the file
    up to its last complete chunk (a ``record`` event, ``repaired``), so the `mcap` package's
    default reader reads it too, and the file says it was cut and how much of its planned
    length is missing."""
    daemon, eps, client = daemon
    sub = events(eps)
    try:
        started = client.record_start("cut-short", seconds=120)
        marker = os.path.join(os.path.dirname(started["file"]), ".cut-short.mcap.writing")
        holding(started["file"], 100)
        assert os.path.exists(marker)
        os.kill(recorder_pid(daemon), signal.SIGKILL)
        seen = {}
        while len(seen) < 2:  # (in either order: the loop says one, the new recorder the other)
            event = wait_event(sub, lambda e: e["kind"] == "recorder" or e["kind"] == "record" and e["action"] == "repaired")
            seen[event["kind"]] = event
        assert "restarted" in seen["recorder"]["cause"]
        repaired = seen["record"]
        assert repaired["name"] == "cut-short" and repaired["file"] == started["file"], repaired
        assert repaired["cause"] == LEFT_CAUSE and repaired["messages"] > 100
        logged = f"pneumad recorder WARNING: recording {started['file']} repaired: {LEFT_CAUSE}"
        deadline = time.monotonic() + 30.0  # the log's line and the event leave the recorder together
        while logged not in daemon.log.read_text():
            assert time.monotonic() < deadline, daemon.log.read_text()[-2000:]
            time.sleep(0.1)
        with open(started["file"], "rb") as f:
            default = [json.loads(m.data)["cycle"] for _, c, m in make_reader(f).iter_messages(topics=["/pneumad/state"])]
        contents = mcap_log.read(started["file"])
        assert len(default) > 100 and default == [m["cycle"] for m in contents.messages["state"]]
        assert contents.truncated.startswith(LEFT_CAUSE + "; closed at its last complete chunk on ")
        notice = recording.open_run(started["file"]).cut_notice("cut-short.mcap")
        assert re.search(r"of the 12\d\.\d s planned: about 1\d\d\.\d s missing at its end$", notice), notice
        assert not os.path.exists(marker)
        for _ in range(50):  # the new recorder is starting
            try:
                again = client.record_start("after", seconds=0.5)
                break
            except RemoteError as exc:
                assert exc.data["reason"] == "recorder_unavailable", exc
                time.sleep(0.2)
        assert finished(client, again["name"]) and len(mcap_log.read(again["file"]).messages["state"]) > 100
    finally:
        sub.close()


def test_a_timed_recording_holds_its_seconds_of_the_daemons_time_when_the_recorder_falls_behind(daemon):
    """``record.start --seconds 1`` with the recorder held up for 2 s right after (as a loaded PC
    holds a nice-5 process): it catches up and records 1 s of the daemon's samples from its start,
    not 1 s of its own time (which had passed while it was held: the recording ended at once)."""
    daemon, _, client = daemon
    started = client.record_start("held-up", seconds=1.0)
    pid = recorder_pid(daemon)
    os.kill(pid, signal.SIGSTOP)
    try:
        time.sleep(2.0)
    finally:
        os.kill(pid, signal.SIGCONT)
    samples = mcap_log.read(finished(client, started["name"])).messages["state"]
    t = [s["t"] for s in samples]
    assert t[-1] - t[0] >= 1.0 and all(b > a for a, b in zip(t, t[1:])), (t[0], t[-1])


def test_a_recording_made_across_a_messenger_restart_keeps_its_time_order(daemon):
    """The recorder behind its feed (held still, as a loaded PC holds a nice-5 process) when
    the messenger is killed: what the old messenger handed on and the recorder had not read yet
    comes before what the new one hands on (the messenger binds the feed, the recorder
    connects: one queue, in order). With the feed bound on the recorder's side the two
    messengers' queues were read in turns, and the file held hundreds of samples out of order.
    Cycles no messenger passed on are missing where the file says so, on /pneumad/gap."""
    daemon, eps, client = daemon
    sub = events(eps)
    recorder = recorder_pid(daemon)
    try:
        started = client.record_start("across-a-restart")
        holding(started["file"], 100)
        os.kill(recorder, signal.SIGSTOP)
        try:
            time.sleep(0.5)  # the old messenger's feed queues up
            os.kill(client.status()["helpers"]["messenger"]["pid"], signal.SIGKILL)
            restarted = wait_event(sub, lambda e: e["kind"] == "messenger")  # the new one serves, a second has passed
        finally:
            os.kill(recorder, signal.SIGCONT)
        for _ in range(50):  # a request in flight as the messenger died is lost: asked again
            try:
                stopped = client.record_stop(started["name"])
                break
            except TimeoutError:
                pass
    finally:
        sub.close()
    with open(stopped["file"], "rb") as f:
        times, cycles, said, holes, gaps = {}, [], [], [], []
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):  # in the file's order
            times.setdefault(channel.topic, []).append(message.log_time)
            if channel.topic == "/pneumad/gap":
                gap = json.loads(message.data)
                gaps.append(gap["missing"])
                if gap["topic"] == "state":
                    said.append(len(cycles))  # before the next state sample
            elif channel.topic == "/pneumad/state":  # its sequence number is the cycle
                if cycles and message.sequence != cycles[-1] + 1:
                    holes.append(len(cycles))
                cycles.append(message.sequence)
    for topic in ("/pneumad/state", "/joint_states"):
        t = times[topic]
        late = sum(b < a for a, b in zip(t, t[1:]))
        assert late == 0 and len(t) == len(cycles), (topic, late, len(t), len(cycles))
    # samples from before the restart and after it (as many as the loop's rate made: a loaded
    # PC's loop may run a few hundred cycles a second)
    assert cycles[0] < restarted["cycle"] < cycles[-1], (cycles[0], restarted["cycle"], cycles[-1])
    # What no messenger passed on (the old one's last batches, if the rings did not hold them
    # across its restart: a loaded PC may keep them all) is said where it is missing: every
    # hole in the cycles has a state gap before the sample after it, every gap stands at a hole,
    # and the stop's count is the file's.
    assert said == holes and sum(gaps) == stopped["gaps"], (said, holes, gaps, stopped["gaps"])
