"""Telemetry and requests through the messenger process: what subscribers see is what the loop
had, and a messenger that dies is replaced while the loop goes on."""
import math
import os
import signal
import subprocess
import sys
import threading
import time

import msgpack
import pytest
import zmq

from bench.common import child_process
from daemon import assembly
from daemon.client.feeds import Subscription
from daemon.messenger.process import MessengerError
from daemon.loop.port import ZmqServer
from tests.daemons import real_daemon, running
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.loop import dealer, make_loop, ok
from daemon.wire import protocol
from daemon.wire.cycle_layout import MODES
from daemon.wire.telemetry_rows import HEADER, LayoutMismatch, state_message
from hal import config


@pytest.fixture
def served():
    loop, captured, srv = make_loop(server=True)
    yield loop, captured, srv
    srv.close()


def subscriber(srv, topics=(b"",)) -> zmq.Socket:
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    for topic in topics:
        sub.setsockopt(zmq.SUBSCRIBE, topic)
    sub.connect(srv.endpoints["telemetry"])
    return sub


def received(sub, loop, wanted, limit_s: float = 20.0):
    """Run the loop (a few cycles at a time, in real time enough for the messenger) until
    ``wanted(topic, message)`` is true of a message the subscriber got; that message."""
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        loop.run(10)
        while sub.poll(1):
            topic, payload = sub.recv_multipart()
            message = msgpack.unpackb(payload, raw=False)
            if wanted(topic.decode(), message):
                return message
    raise AssertionError("the subscriber did not get the message in time")


def test_a_state_row_holds_the_loops_own_values(served):
    loop, captured, _ = served
    loop.enable()
    loop.run(1000)  # the last cycle completes a batch of 10
    last = captured.of("state")[-1]
    assert set(last) == {"seq", "layout", *loop.layout.names} and last["layout"] == loop.layout.id
    assert last["cycle"][-1] == loop.cycle
    for i, j in enumerate(("bottom", "middle")):
        assert last[f"{j}.position"][-1] == loop.angles[i]
        assert last[f"{j}.velocity"][-1] == loop.velocities[i]
        assert last[f"{j}.setpoint"][-1] == loop.reference[0][i]
        assert last[f"{j}.error"][-1] == loop.reference[0][i] - loop.angles[i]
        assert last[f"{j}.u.v_mv"][-1] == loop.u[i]
        assert last[f"{j}.p_head_cmd"][-1] == loop.p_head[i] and last[f"{j}.p_rod_cmd"][-1] == loop.p_rod[i]
        assert math.isnan(last[f"{j}.shadow.v_mv"][-1])  # no candidate runs
    assert [last[f"out.{ch.name}"][-1] for ch in loop.io.transport.outputs] == list(loop.io.last_volts)
    assert last["force"][-1] == loop.snapshot.measured[0]
    assert last["mode"][-1] == "enabled"


def test_outside_enabled_no_command_is_in_force_and_the_safe_pressures_are_the_commanded(served):
    loop, captured, _ = served
    loop.run(20)
    last = captured.of("state")[-1]
    assert last["mode"] == ["idle"] * 10
    assert all(math.isnan(u) for u in last["bottom.u.v_mv"] + last["middle.u.v_mv"])
    assert last["bottom.p_head_cmd"][-1] == loop.io.safe_pressures[0][0]


def test_subscribers_get_the_same_messages_as_the_loop_sent(served):
    loop, captured, srv = served
    sub = subscriber(srv, (b"state",))
    first = received(sub, loop, lambda topic, m: True)
    sent = next(m for m in captured.of("state") if m["seq"] == first["seq"])
    assert msgpack.packb(first) == msgpack.packb(sent)  # every column (bytes: a NaN is equal to itself)
    assert first["mode"] == sent["mode"] == ["idle"] * 10


def test_a_state_batch_reads_back_one_column_per_field_of_the_layout():
    """A muscle rig's batch: each column holds its field of every row, ``cycle`` an integer,
    ``mode`` by name; a batch of another layout is refused, never read wrong."""
    layout = assembly.cycle_layout(config.load("sim-muscle"))
    body = bytearray(HEADER.size + 4 * layout.row.size)
    HEADER.pack_into(body, 0, 42, layout.id, 4)
    rows = []
    for i in range(4):
        values = [float(100 * i + k) for k in range(layout.width)]
        values[0], values[layout["mode"].index] = 7 + i, i % len(MODES)
        layout.row.pack_into(body, HEADER.size + i * layout.row.size, *values)
        rows.append(values)
    message = state_message(layout, bytes(body))
    assert list(message) == ["seq", "layout", *layout.names] and message["seq"] == 42
    assert message["cycle"] == [7, 8, 9, 10] and all(type(c) is int for c in message["cycle"])
    for f in layout.fields[1:-1]:
        assert message[f.name] == [v[f.index] for v in rows], f.name
    assert message["mode"] == [MODES[i % len(MODES)] for i in range(4)]
    assert message["elbow.p_a_cmd"] != message["elbow.p_a"]  # commanded and measured, each its own
    other = assembly.cycle_layout(config.load())
    with pytest.raises(LayoutMismatch, match="layout"):
        state_message(other, bytes(body))


def test_a_messenger_that_dies_is_replaced_and_the_loop_goes_on(served, capfd):
    loop, captured, srv = served
    sub = subscriber(srv)
    before = received(sub, loop, lambda topic, m: topic == "state")["seq"]
    spare = _spare_waiting(loop, srv)
    os.kill(srv.messenger._proc.pid, signal.SIGKILL)
    cycles = loop.cycle
    event = received(sub, loop, lambda topic, m: topic == "event" and m["kind"] == "messenger")
    assert "restarted" in event["cause"]
    after = received(sub, loop, lambda topic, m: topic == "state")["seq"]
    assert after > before + 1  # the messages sent while no messenger was there are missed, and seen to be
    assert loop.cycle > cycles and loop.state.value == "idle"  # the loop ran on, untouched
    status = ok(loop, dealer(srv), "status")  # the command sockets are back too
    assert status["telemetry"]["messenger_running"] and status["telemetry"]["messenger_restarts"] == 1
    helper = status["helpers"]["messenger"]
    assert helper["running"] and helper["restarts"] == 1 and helper["last_exit_code"] == -signal.SIGKILL
    assert helper["pid"] == spare  # the spare, started ahead, took over
    assert "pneumad messenger ERROR: messenger: the messenger process exited (code -9) and was restarted " \
           "(restart 1)" in capfd.readouterr().err  # the daemon's log: the new messenger's stderr


def _spare_waiting(loop, srv, renew=None, limit_s: float = 60.0) -> int:
    """Run the loop until the messenger's spare has been started (at a look after the
    messenger said it was ready) and has reached its standby (``renew()`` called meanwhile);
    its pid."""
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        loop.run(100)
        if renew is not None:
            renew()
        spare = srv.messenger._proc._spare
        if spare is not None and _waits_on_stdin(spare.pid):
            return spare.pid
        time.sleep(0.01)
    raise AssertionError("no spare messenger was started")


def _waits_on_stdin(pid: int) -> bool:
    """Whether the process is blocked reading its stdin (a spare at Child.standby): its
    system call is read(0, ...)."""
    try:
        with open(f"/proc/{pid}/syscall") as f:
            call = f.read().split()
    except OSError:
        return False
    return len(call) > 1 and call[0] == "0" and int(call[1], 16) == 0


def _kill_messenger(srv) -> None:
    """SIGKILL to the messenger in service, and wait until it has died (a child of this
    process: its end is waited for, not reaped): the virtual clock runs the loop's second
    faster than a loaded machine's kernel ends a process."""
    pid = srv.messenger._proc.pid
    os.kill(pid, signal.SIGKILL)
    os.waitid(os.P_PID, pid, os.WEXITED | os.WNOWAIT)


def _messenger_back(loop, srv) -> None:
    """The new messenger (started by a look the loop's cycles ran) ready, waited for in real
    time while the loop stands still, then the loop run to its next look, which sees it."""
    assert srv.messenger.down
    srv.messenger._proc.wait_ready(60.0)
    loop.run(100)
    assert not srv.messenger.down


def _renewed(loop, sock, lease, limit_s: float = 60.0) -> dict:
    """``lease.renew`` on ``sock``, sent again until a messenger passes it on and the loop
    answers (one sent as the messenger died is lost with it)."""
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        sock.send(protocol.encode_request(1, "lease.renew", None, lease))
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            loop.run(1)  # the virtual clock moves by the cycles run, a cycle per poll below
            if sock.poll(1):
                return msgpack.unpackb(sock.recv_multipart()[-1], raw=False)
    raise AssertionError("the renewal never came through")


def test_a_messenger_restart_never_takes_a_held_lease_and_a_client_gone_meanwhile_still_loses_it(served):
    """The lease's clock is held while the messenger that carries its renewals is down or
    restarting; once a new one is ready the holder has its ttl from then. The restart is made
    slow (its spare stopped: a loaded machine) while the loop runs three of the lease's ttls
    on the virtual clock: without the hold, the arm trips."""
    loop, captured, srv = served
    sock = dealer(srv)
    lease = ok(loop, sock, "lease.acquire", {"ttl_s": 0.3})["lease"]
    ok(loop, sock, "enable", lease=lease)
    renew = lambda: ok(loop, sock, "lease.renew", lease=lease)  # noqa: E731

    def slow_restart() -> None:
        """The messenger killed, its spare held back while the loop runs 1 s."""
        spare = _spare_waiting(loop, srv, renew)
        renew()
        os.kill(spare, signal.SIGSTOP)
        try:
            _kill_messenger(srv)
            loop.run(1000)  # 1 s of the loop's time with no messenger passing renewals on
            assert srv.messenger.down and srv.messenger._proc.pid == spare
        finally:
            os.kill(spare, signal.SIGCONT)

    slow_restart()
    assert loop.state.value == "enabled", loop.supervisor.cause  # held while no messenger could pass a renewal on
    _messenger_back(loop, srv)
    assert _renewed(loop, sock, lease)["ok"] and loop.state.value == "enabled"  # the held lease, renewed
    assert not any(m["kind"] == "trip" for m in captured.of("event"))
    # A client that stops renewing during a restart loses its lease ttl after the new messenger is ready.
    slow_restart()
    assert loop.state.value == "enabled"
    _messenger_back(loop, srv)
    ready_seen = loop.clock.now()
    loop.run(500)  # the ttl, and more
    trip = next(m for m in captured.of("event") if m["kind"] == "trip")
    assert "lease lost" in trip["cause"] and ready_seen - 0.1 + 0.3 <= trip["t"] <= ready_seen + 0.3 + 0.01
    assert loop.state.value == "fault" and srv.messenger.restarts == 2


def test_a_telemetry_endpoint_in_use_is_a_clear_error():
    ctx = zmq.Context.instance()
    squatter = ctx.socket(zmq.PUB)
    port = squatter.bind_to_random_port("tcp://127.0.0.1")
    try:
        with pytest.raises(MessengerError, match=f"cannot bind the telemetry endpoint tcp://127.0.0.1:{port}"):
            ZmqServer("tcp://127.0.0.1:*", "tcp://127.0.0.1:*", f"tcp://127.0.0.1:{port}",
                      layout=assembly.cycle_layout(config.load()))
    finally:
        squatter.close(linger=0)


def test_the_messenger_dies_with_the_daemon(tmp_path):
    """SIGKILL to the daemon (no chance to stop its children): the messenger goes too."""
    daemon, _ = real_daemon(tmp_path)
    try:
        messenger = _wait_for_child(daemon.pid, "daemon.messenger.process")
        daemon.send_signal(signal.SIGKILL)
        daemon.wait(STOP_WAIT_S)
        end = time.monotonic() + 30.0  # its end is waited for: a busy machine schedules it late
        while running(messenger) and time.monotonic() < end:
            time.sleep(0.05)
        assert not running(messenger)
    finally:
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait()


def _wait_for_child(parent: int, marker: str, limit_s: float = 60.0) -> int:
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        pid = child_process(parent, marker)
        if pid is not None:
            return pid
        time.sleep(0.1)
    raise AssertionError(f"no child process of {parent} running {marker}")


@pytest.mark.slow(seconds=4)  # a few seconds: kept out of the fast subset
def test_stopping_the_whole_process_group_still_publishes_the_shutdown(tmp_path):
    """systemctl stop and Ctrl-C signal every process of the daemon: the messenger waits for
    the daemon's last events instead of dying first."""
    daemon, eps = real_daemon(tmp_path, start_new_session=True)
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.connect(eps["telemetry"])
    try:
        assert sub.poll(60_000), "no telemetry from the daemon"
        os.killpg(daemon.pid, signal.SIGTERM)
        kinds = []
        end = time.monotonic() + 60.0  # the event is waited for; the bound only ends a hang
        while "shutdown" not in kinds and time.monotonic() < end:
            if sub.poll(100):
                topic, payload = sub.recv_multipart()
                if topic == b"event":
                    kinds.append(msgpack.unpackb(payload, raw=False)["kind"])
        assert "shutdown" in kinds
        assert daemon.wait(STOP_WAIT_S) == 0
    finally:
        sub.close()
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait()


def test_a_corrupt_request_ring_stops_the_arm_and_the_loop_serves_on(served):
    loop, _, srv = served
    sock = dealer(srv)
    lease = ok(loop, sock, "lease.acquire")["lease"]
    ok(loop, sock, "enable", lease=lease)
    ring = srv.rings["command"]
    ring.put(1, b"x")  # an entry whose length field is then made impossible
    with open(ring.path, "r+b") as f:
        f.seek(64 + ring._read.value % ring.capacity)
        f.write((ring.capacity * 2).to_bytes(4, "little"))
    loop.run(1)
    assert loop.state.value == "fault" and "claims" in loop.supervisor.cause
    assert ok(loop, sock, "ping")["pong"]  # the ring was emptied and serves again


def test_rings_a_killed_daemon_left_behind_are_reclaimed_by_the_next_one(tmp_path):
    """SIGKILL leaves a daemon no time to remove its shared-memory rings (4 MiB in /dev/shm);
    the next daemon removes every rings directory whose process is gone, and no other."""
    from daemon.loop.port import RINGS_PREFIX, reclaim_stale_rings

    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    stale, live, other = (tmp_path / f"{RINGS_PREFIX}{gone.pid}-x1", tmp_path / f"{RINGS_PREFIX}{os.getpid()}-x2",
                          tmp_path / "unrelated")
    for d in (stale, live, other):
        d.mkdir()
        (d / "command").write_bytes(b"\0" * 64)
    assert reclaim_stale_rings(str(tmp_path)) == [stale.name]
    assert not stale.exists() and live.exists() and other.exists()


class StatsAndEvents:
    """A real ZeroMQ publisher made by the test: every 20 ms a ``stats`` message, then an
    ``event`` of the same ``seq`` (as the daemon's loop publishes both on one socket)."""

    def __init__(self, endpoint: str, stats: bool = True):
        self.pub = zmq.Context.instance().socket(zmq.PUB)
        self.pub.setsockopt(zmq.LINGER, 0)
        self.pub.bind(endpoint)
        self.stop, self.stats = threading.Event(), stats
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        seq = 0
        while not self.stop.wait(0.02):
            seq += 1
            if self.stats:
                self.pub.send_multipart([b"stats", msgpack.packb({"seq": seq})])
            self.pub.send_multipart([b"event", msgpack.packb({"seq": seq, "kind": "test"})])

    def close(self):
        self.stop.set()
        self.thread.join(5)
        self.pub.close()


def test_a_subscription_heard_by_its_publisher_gets_what_is_published_after(tmp_path):
    """ZeroMQ drops what a publisher sends before a new subscription reaches it, and cannot say
    when one has: wait_until_heard takes the first ``stats`` message (subscribed last) as the
    sign. The event published right after that message is received; a stats message is never
    handed to a subscriber that did not ask for it; a publisher without stats is a clear error."""
    endpoint = f"ipc://{tmp_path}/telemetry"
    pub = StatsAndEvents(endpoint)
    context = zmq.Context.instance()
    try:
        both = Subscription(context, endpoint, (b"stats", b"event"))  # stats given first: subscribed last all the same
        both.wait_until_heard(limit_s=20.0)
        got = [both.receive(5.0)]
        while got[-1][0] != "stats":  # (events the publisher had the subscription for a little earlier)
            got.append(both.receive(5.0))
        assert both.receive(5.0) == ("event", {"seq": got[-1][1]["seq"], "kind": "test"})
        both.close()
        events = Subscription(context, endpoint, (b"event",))
        events.wait_until_heard(limit_s=20.0)
        got = [events.receive(5.0) for _ in range(20)]
        assert {topic for topic, _ in got} == {"event"}
        assert [m["seq"] for _, m in got] == list(range(got[0][1]["seq"], got[0][1]["seq"] + 20))
        events.close()
    finally:
        pub.close()
    quiet = StatsAndEvents(f"ipc://{tmp_path}/quiet", stats=False)
    try:
        events = Subscription(context, f"ipc://{tmp_path}/quiet", (b"event",))
        with pytest.raises(TimeoutError, match=r"no stats message from the daemon within 0\.5 s"):
            events.wait_until_heard(limit_s=0.5)
        assert events.receive(5.0)[0] == "event"  # what came meanwhile is kept
        events.close()
    finally:
        quiet.close()
