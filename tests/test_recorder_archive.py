"""The recorder's archive (daemon/recorder/archive.py) in this process, fed a loop's telemetry
from a virtual clock: a stop it cannot catch up to says how far behind the file ends, and a
recorder finishes only the files no live recorder is writing. (Against a real daemon:
tests/test_recorder.py.)"""
import json
import os
import time

import msgpack
import zmq
from mcap.reader import make_reader

from daemon.recorder import process as recorder_process
from daemon.recorder.archive import LEFT_CAUSE, Archive
from daemon.testing.loop import Captured, dealer, make_loop, ok
from daemon.wire import protocol as P


def daemons_rings(tmp_path, cycles: int) -> tuple[object, Captured]:
    """A loop run ``cycles`` cycles on a virtual clock, and a rings' directory holding what a
    daemon writes there at start (``describe.json``, ``controller.json``): (its path, the
    telemetry captured)."""
    loop, captured, srv = make_loop(server=True)
    sock = dealer(srv)
    describe, controller = ok(loop, sock, "describe"), ok(loop, sock, "controller.get")
    loop.run(cycles)
    srv.close()
    rings = tmp_path / "rings"
    rings.mkdir()
    (rings / "describe.json").write_text(json.dumps(describe))
    (rings / "controller.json").write_text(json.dumps(controller))
    return rings, captured


def test_a_recorder_that_cannot_catch_up_before_a_stop_says_how_far_behind_it_ends_the_file(tmp_path, monkeypatch):
    """Past its catch-up (1 s; here none), a stop ends the file where the recorder got to, and
    its cause says about how far behind the daemon that is: nothing cut short in silence. A
    real feed (ZeroMQ PUSH to PULL) holding a short run's telemetry, stamped seconds before now,
    and no mark of the stop in it."""
    rings, captured = daemons_rings(tmp_path, 300)
    events = []
    archive = Archive(str(rings), str(tmp_path / "recordings"), 1e9, 0.0, events.append)
    lag = time.monotonic() - 5.0  # [s] the run's virtual clock placed 5 s in the daemon's past
    states = []
    for topic, message in captured.messages:
        if topic == "state":
            states.append(msgpack.packb({**message, "t": [t + lag for t in message["t"]]}))
    ctx = zmq.Context.instance()
    feed, messenger = ctx.socket(zmq.PULL), ctx.socket(zmq.PUSH)
    for s in (feed, messenger):
        s.setsockopt(zmq.LINGER, 0)
    feed.bind(f"ipc://{tmp_path}/feed")
    messenger.connect(f"ipc://{tmp_path}/feed")
    try:
        archive.message("state", states[0])
        archive.start("late", "alice")
        for body in states[1:]:
            messenger.send_multipart([b"state", body])
        assert feed.poll(5000)
        monkeypatch.setattr(recorder_process, "CATCH_UP_S", 0.0)
        archive.behind_s = recorder_process._catch_up(feed, archive, [], b"the stop's mark, never reached")
        reply = msgpack.unpackb(archive.request(P.encode_request(1, "record.stop", {"name": "late"}), "alice"))
        after = time.monotonic() - lag  # [s] the most it can be behind, however long this took
    finally:
        feed.close()
        messenger.close()
    stopped = reply["result"]
    assert stopped["cause"].startswith("record.stop from alice; the recorder had not caught up"), stopped["cause"]
    behind = float(stopped["cause"].split("the file ends about ")[1].split(" s before")[0])
    assert 4.9 < behind <= after + 0.01, stopped["cause"]
    assert events[-1]["cause"] == stopped["cause"]  # the record event says it too


def test_a_recorder_finishes_only_the_files_no_live_recorder_is_writing(tmp_path, caplog):
    """Two daemons' recorders on one directory: one starting (a daemon started beside another)
    leaves the other's recording in progress alone (its lock), and finishes it once its writer
    is gone without finishing it (the file closed as a killed process's is): an event and a
    line in the daemon's log."""
    rings, captured = daemons_rings(tmp_path, 2000)
    said_a, said_b = [], []
    a = Archive(str(rings), str(tmp_path / "recordings"), 1e9, 0.0, said_a.append)
    b = Archive(str(rings), str(tmp_path / "recordings"), 1e9, 0.0, said_b.append)
    writing = a.start("writing", "alice")
    for topic, message in captured.messages:
        a.message(topic, msgpack.packb(message))
    size = os.path.getsize(writing.path)
    b.finish_left_files()
    assert said_b == [] and os.path.getsize(writing.path) == size  # a's, still being written: untouched
    writing.file.close()  # a's recorder gone, the file not finished (no footer)
    b.finish_left_files()
    assert [(e["action"], e["name"]) for e in said_b] == [("repaired", "writing")] and said_b[0]["messages"] > 1000
    assert f"recording {writing.path} repaired: {LEFT_CAUSE}" in caplog.text
    assert not (tmp_path / "recordings" / ".writing.mcap.writing").exists()
    with open(writing.path, "rb") as f:
        assert sum(1 for _ in make_reader(f).iter_messages(topics=["/pneumad/state"])) > 1000
    b.finish_left_files()
    assert len(said_b) == 1  # once
