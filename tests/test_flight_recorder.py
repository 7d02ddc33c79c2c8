"""The flight recorder (docs/recordings.md, "The flight recorder"): a real daemon's e-stop, its
stalled loop and its transport gone stale each name a flight file in their event (and their
journal line), and the file holds the seconds before them, readable by ``pneumactl export``,
:func:`mcap_log.read` and the ``mcap`` library; a storm of e-stops writes one file while it
lasts and at most the hourly cap of files, and what is held stays bounded; ``record.snapshot``
writes one on demand."""
import csv
import os
import signal
import subprocess
import sys
import time

import msgpack
import pytest
from mcap.reader import make_reader

from bench.wires import listening
from daemon.client.client import Client
from daemon.recorder.flight import KEEP_MARGIN_S, MAX_FILES_PER_HOUR, MEMORY_CAP_BYTES, FlightRecorder
from daemon.recordings import mcap_log
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.loop import dealer, make_loop, ok
from daemon.testing.ports import free_tcp_port
from daemon.wire.flight import FlightNames, Window
from hal.rig_sections import FlightRecorderConfig
from tests.daemons import TOLERANT_STALL, real_daemon, tolerant_rig_text, wait_for_own_daemon
from tests.test_journal import journal_line, next_event
from tests.wirehelpers import start_peer, stop_peer

SECONDS, AFTER_S = 4.0, 1.0


def flight_rig(tmp_path, stall_after_s: float = 5.0, seconds: float = SECONDS, after_s: float = AFTER_S):
    path = tmp_path / "flight-rig.toml"
    path.write_text(tolerant_rig_text().replace(TOLERANT_STALL, f"stall_after_s = {stall_after_s} ")
                    + f"\n[flight_recorder]\nseconds = {seconds}\nafter_s = {after_s}\n")
    return path


def written(sub, name: str, limit_s: float = 60.0) -> dict:
    """The ``record`` event saying flight file ``name`` is written."""
    return next_event(sub, "record", limit_s, action="flight", name=name)


def assert_holds_the_seconds_before(path, event: dict, tmp_path, after: bool = True) -> None:
    """The file holds state from ``SECONDS`` before ``event`` (a sample within the first half
    second of its window) up to it (and past it, ``after``: a loop whose transport is lost
    publishes no state), the event itself, and every reader opens it."""
    contents = mcap_log.read(path)
    assert not contents.truncated
    t = [s["t"] for s in contents.messages["state"]]
    assert t[0] <= event["t"] - SECONDS + 0.5 and t[-1] >= event["t"] + (0.5 if after else -0.05), \
        (t[0], t[-1], event["t"])
    assert any(e.get("seq") == event["seq"] for e in contents.messages["event"])
    with open(path, "rb") as f:
        states = sum(1 for _ in make_reader(f).iter_messages(topics=["/pneumad/state"]))
    assert states == len(t)
    out = tmp_path / f"{os.path.basename(path)}.csv"
    done = subprocess.run([sys.executable, "-m", "daemon.client.ctl", "export", str(path), str(out)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    with open(out) as f:
        assert sum(1 for _ in csv.reader(f)) > len(t) // 2


@pytest.mark.slow(seconds=40)
def test_an_estop_and_a_stalled_loop_each_write_the_seconds_before_them_named_in_their_journal_line(tmp_path):
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:  # a stall limit of 2 s: the loop process stopped for 3 s trips
        daemon, eps = real_daemon(tmp_path, "--config", str(flight_rig(tmp_path, stall_after_s=2.0)), stderr=stderr)
    recordings = tmp_path / "recordings"
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            sub = client.subscribe((b"event",))
            sub.wait_until_heard()
            client.acquire_lease(30.0)  # (a loaded machine lets a 2 s lease lapse: not what is tested here)
            client.keep_lease()
            client.enable()
            time.sleep(SECONDS + 1.0)  # the flight recorder holds its seconds
            client.estop()
            estop = next_event(sub, "estop")
            assert estop["flight"].startswith("flight-") and estop["flight"].endswith(f"-estop-c{estop['cycle']}")
            assert f"flight recording {estop['flight']}.mcap" in journal_line(log, "WARNING", "estop", estop)
            done = written(sub, estop["flight"])
            assert done["file"] == str(recordings / f"{estop['flight']}.mcap")
            assert done["from_t"] == pytest.approx(estop["t"] - SECONDS) and done["to_t"] == pytest.approx(
                estop["t"] + AFTER_S)
            assert estop["flight"] in [f["name"] for f in client.record_list()["files"]]
            assert_holds_the_seconds_before(done["file"], estop, tmp_path)

            client.reset()
            client.enable()
            time.sleep(SECONDS + 1.0)
            os.kill(daemon.pid, signal.SIGSTOP)  # the loop's own process: its helpers run on
            try:
                time.sleep(3.0)
            finally:
                os.kill(daemon.pid, signal.SIGCONT)
            trip = next_event(sub, "trip")
            assert "stalled" in trip["cause"] or "stale" in trip["cause"], trip
            assert f"flight recording {trip['flight']}.mcap" in journal_line(log, "ERROR", "trip", trip)
            done = written(sub, trip["flight"])
            assert_holds_the_seconds_before(done["file"], trip, tmp_path)
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


@pytest.mark.slow(seconds=40)
def test_a_transport_gone_stale_trips_and_its_flight_file_holds_the_seconds_before(tmp_path):
    """Over Modbus, its server (the simulated rig's peer process) killed with the arm enabled:
    no fresh input, a trip (stale, or the link down), whose flight file holds what led up to it."""
    port = free_tcp_port()
    server = start_peer("sim_backend.modbus_peer", "--port", str(port), ready=lambda: listening(port))
    try:
        daemon, eps = real_daemon(tmp_path, "--config", str(flight_rig(tmp_path)), "--transport", "modbus",
                                  "--transport-option", f"port={port}", "--transport-option", "open_timeout_s=60",
                                  "--transport-option", "timeout_s=0.5", "--safety", "stale_after_s=1.0")
        try:
            with Client(**eps, timeout=20.0) as client:
                wait_for_own_daemon(client, daemon)
                sub = client.subscribe((b"event",))
                sub.wait_until_heard()
                client.acquire_lease(30.0)  # (a loaded machine lets a 2 s lease lapse: not what is tested here)
                client.keep_lease()
                client.enable()
                time.sleep(SECONDS + 1.0)
                stop_peer(server, hard=True)
                trip = next_event(sub, "trip")
                assert "stale" in trip["cause"] or "modbus" in trip["cause"], trip
                done = written(sub, trip["flight"])
                assert_holds_the_seconds_before(done["file"], trip, tmp_path, after=False)
        finally:
            daemon.terminate()
            daemon.wait(STOP_WAIT_S)
    finally:
        stop_peer(server)


@pytest.mark.slow(seconds=60)
def test_a_storm_of_estops_writes_one_file_while_it_lasts_and_no_more_files_than_the_cap(tmp_path):
    """Ten e-stops in a burst share one file; then e-stops each past the last one's window
    open a file each until the hourly cap, past which an e-stop's file is a ``failed`` event."""
    daemon, eps = real_daemon(tmp_path, "--config", str(flight_rig(tmp_path, seconds=1.0, after_s=2.0)))
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            sub = client.subscribe((b"event",))
            sub.wait_until_heard()
            client.acquire_lease(30.0)  # (a loaded machine lets a 2 s lease lapse: not what is tested here)
            client.keep_lease()
            names = []
            for _ in range(10):
                client.estop()
                names.append(next_event(sub, "estop")["flight"])
                client.reset()
            assert len(set(names)) == 1, names
            for _ in range(MAX_FILES_PER_HOUR):
                time.sleep(2.5)  # past the window of the one before (2 s after it)
                client.estop()
                names.append(next_event(sub, "estop")["flight"])
                client.reset()
            assert len(set(names)) == MAX_FILES_PER_HOUR + 1
            refused = next_event(sub, "record", action="failed", name=names[-1])
            assert f"{MAX_FILES_PER_HOUR} files in the last hour" in refused["cause"]
            deadline = time.monotonic() + 60.0
            while client.record_list()["flight"]["due"]:
                assert time.monotonic() < deadline, client.record_list()["flight"]
                time.sleep(0.2)
            files = [f["name"] for f in client.record_list()["files"]]
            assert sorted(files) == sorted(set(names[:-1]))
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


@pytest.mark.slow(seconds=20)
def test_a_snapshot_writes_the_held_seconds_on_request(tmp_path):
    daemon, eps = real_daemon(tmp_path, "--config", str(flight_rig(tmp_path)))
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            sub = client.subscribe((b"event",))
            time.sleep(SECONDS + 1.0)
            held = client.record_list()["flight"]
            assert held["seconds"] == SECONDS and held["held_s"] >= SECONDS and 0 < held["held_bytes"] < 64e6
            asked = client.record_snapshot("before-the-lunch")
            assert asked["to_t"] - asked["from_t"] == pytest.approx(SECONDS)
            done = written(sub, "before-the-lunch")
            t = [s["t"] for s in mcap_log.read(done["file"]).messages["state"]]
            assert t[0] <= asked["from_t"] + 0.1 and t[-1] == pytest.approx(asked["to_t"])
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


def test_events_close_together_share_a_flight_file_and_only_trips_estops_and_stalls_name_one():
    names = FlightNames(after_s=3.0)
    assert names.name_for({"kind": "state", "t": 1.0}) is None
    first = names.name_for({"kind": "trip", "t": 10.0, "cycle": 10000})
    assert first.endswith("-trip-c10000")
    assert names.name_for({"kind": "estop", "t": 12.0, "cycle": 12000}) == first  # within 3 s: the same
    assert names.window.end_t == 15.0  # pushed on by the later one
    assert names.name_for({"kind": "loop_stalled", "t": 15.5, "cycle": 15000}) != first
    window = Window(0.0, 3.0)
    for t in range(0, 200, 2):  # a storm: its file's end stops 60 s past its first event
        if window.covers(t):
            window.extend(t, 3.0)
    assert window.end_t == 60.0


@pytest.fixture(scope="module")
def published():
    """A second of an in-process loop's telemetry as published (msgpack bytes), its describe
    and controller."""
    loop, captured, srv = make_loop(server=True)
    sock = dealer(srv)
    describe, controller = ok(loop, sock, "describe"), ok(loop, sock, "controller.get")
    start = len(captured.messages)
    loop.enable()
    loop.run(1000)
    srv.close()
    return describe, controller, [(topic, msgpack.packb(m)) for topic, m in captured.messages[start:]]


def test_a_storm_longer_than_the_held_seconds_keeps_its_files_start_and_memory_stays_bounded(tmp_path, published):
    """The flight recorder on a clock of the test's: 30 s of e-stops 0.5 s apart share one file,
    which still begins ``seconds`` before the first (held past the usual span while the file is
    due), and what is held otherwise spans ``seconds + after_s`` and a margin."""
    describe, controller, messages = published
    events, now = [], [0.0]

    def open_file(name):
        path = str(tmp_path / f"{name}.mcap")
        return open(path, "xb"), path

    recorder = FlightRecorder(FlightRecorderConfig(seconds=2.0, after_s=1.0), open_file, lambda path: None,
                              lambda: (describe, controller), events.append, clock=lambda: now[0])
    names = FlightNames(after_s=1.0)
    per_second = len(messages)
    for k in range(50 * per_second):  # 50 s of telemetry, fed by its arrival time
        t = k / per_second
        now[0] = t
        topic, body = messages[k % per_second]
        recorder.take(topic, body, t)
        # an e-stop every half second (twice in each second's messages, whatever their count)
        if 10.0 <= t <= 40.0 and k % per_second in (0, per_second // 2):
            event = {"kind": "estop", "t": t, "cycle": k, "cause": "e-stop from a script"}
            event["flight"] = names.name_for(event)
            recorder.event(event)
        while recorder.work(t, slice_s=float("inf")):
            pass
    written, = [e for e in events if e["action"] == "flight"]
    assert len(written["events"]) == 61 and written["from_t"] == 8.0 and written["to_t"] == 41.0
    assert written["held_from_t"] == pytest.approx(8.0, abs=0.01)
    assert mcap_log.read(written["file"]).messages["state"]
    assert recorder.held[-1][0] - recorder.held[0][0] <= 2.0 + 1.0 + KEEP_MARGIN_S
    assert recorder.bytes == sum(len(m[2]) for m in recorder.held) < MEMORY_CAP_BYTES
