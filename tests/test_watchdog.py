"""The cycle watchdog (daemon/loop/watchdog.py): a controller step that hangs does not hold the
outputs. A real daemon on the simulated rig, through a transport that keeps every write with its
time and the thread that made it (tests.plugins.RecordingTransport): the watchdog thread writes
the safe state while the step still hangs, the messenger says so (a ``watchdog`` event, a log
line), an e-stop during the hang is written at once, and when the step returns its output is
never written and the controller is replaced as a failed one. The same, fast, on a loop in
this process with its watchdog and the two ends of its link (no daemon, no messenger)."""
import dataclasses
import json
import os
import threading
import time

import msgpack
import pytest
import zmq

from controllers.pid import PID
from daemon import assembly
from daemon.loop.clock import MonotonicClock
from daemon.loop.port import ZmqServer
from daemon.loop.safety import State
from daemon.loop.watchdog import CycleWatchdog
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.loop import PRIVATE, dealer
from daemon.wire import protocol as P
from daemon.wire.watchdog_link import WatchdogLink
from hal import config
from daemon.client.client import Client
from tests.daemons import TOLERANT_STALL, real_daemon, tolerant_rig_text, wait_for_own_daemon
from tests.plugins import HANG_S
from tests.schemas import schema
from tests.test_timing import Events, logged

PLUGINS = ("--controller-plugin", "sleeps_hung=tests.plugins:SleepsHung",
           "--controller-plugin", "spins_hung=tests.plugins:SpinsHung")
STALL_S = 0.5  # the stall limit these rigs set [s]: well above this machine's own pauses (tens of ms)
BOUND_S = 1.5  # the safe state must be written within this long of the hang's start, or of an e-stop [s]


def recording_rig(tmp_path, stall_s: float) -> str:
    text = tolerant_rig_text().replace(TOLERANT_STALL, f"stall_after_s = {stall_s}  ")
    text = text.replace('backend = "sim"', 'backend = "tests.plugins:RecordingTransport"')
    text = text.replace("[transport.options]\n", f"[transport.options]\nrecord_to = \"{tmp_path / 'writes.json'}\"\n")
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return str(path)


def hung_daemon(tmp_path, controller: str, stall_s: float, log):
    env = {**os.environ, "PNEUMAD_TEST_HANG_MARK": str(tmp_path / "hang")}
    return real_daemon(tmp_path, "--config", recording_rig(tmp_path, stall_s), *PLUGINS, "--controller", controller,
                       stderr=log, env=env)


def hang_began(tmp_path, limit_s: float = 60.0) -> float:
    """When the step began to hang [s, monotonic], once it has."""
    deadline = time.monotonic() + limit_s
    while not (tmp_path / "hang").exists() or not (tmp_path / "hang").read_text():
        assert time.monotonic() < deadline, "the step never hung"
        time.sleep(0.01)
    return float((tmp_path / "hang").read_text())


def writes(tmp_path) -> list[tuple[float, str, list[float]]]:
    """Every write the daemon made (its first: the safe state, at start), after it stopped."""
    return [tuple(w) for w in json.loads((tmp_path / "writes.json").read_text())["timed"]]


def enabled(client: Client, daemon) -> Events:
    wait_for_own_daemon(client, daemon)
    events = Events(client)
    client.acquire_lease()
    client.keep_lease()
    client.enable()
    return events


def check_the_hang_wrote_safe_then_nothing_else(record, began: float, written_by_watchdog_before: float) -> None:
    """The watchdog's thread wrote the safe state within the bound while the step hung, and
    every write after it is the safe state (the step's own output never reached the outputs)."""
    safe = record[0][2]
    first = next(i for i, (t, thread, _) in enumerate(record) if thread == "cycle watchdog" and t > began)
    t, _, values = record[first]
    assert values == safe and t - began < written_by_watchdog_before
    assert t < began + HANG_S  # before the step returned
    assert all(v == safe for _, _, v in record[first:]), "a command was written after the watchdog's safe state"
    loop_before = [w for w in record[:first] if w[1] != "cycle watchdog"]
    assert loop_before[-1][2] != safe  # the arm was under control until the hang


@pytest.mark.slow(seconds=40)
@pytest.mark.parametrize("controller", ["sleeps_hung", "spins_hung"])
def test_a_hung_step_has_the_watchdog_write_the_safe_state_and_the_controller_replaced_once_it_returns(tmp_path,
                                                                                                      controller):
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:
        daemon, eps = hung_daemon(tmp_path, controller, STALL_S, stderr)
    try:
        with Client(**eps, timeout=20.0) as client:
            events = enabled(client, daemon)
            began = hang_began(tmp_path)
            event = events.next("watchdog", limit_s=30.0)
            schema("telemetry", "event").validate(event)
            assert event["source"] == "messenger"
            assert f"controller {controller}'s step has run" in event["cause"]
            assert "the cycle watchdog wrote the safe state" in event["cause"]
            replaced = events.next("controller", limit_s=30.0)  # once the step returned
            assert replaced["from"] == controller and replaced["to"] == "hold"
            assert replaced["cause"].startswith(f"controller {controller}'s step hung: ")
            status = client.status()
            assert status["state"] == "fault" and status["controller"] == "hold"
            assert f"controller {controller}'s step hung" in status["cause"]
            events.close()
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    check_the_hang_wrote_safe_then_nothing_else(writes(tmp_path), began, STALL_S + BOUND_S)
    logged(log, ("pneumad messenger ERROR: watchdog:", f"controller {controller}'s step has run",
                 "the cycle watchdog wrote the safe state"))


@pytest.mark.slow(seconds=40)
def test_an_estop_while_the_step_hangs_is_written_by_the_watchdog_at_once_and_says_so(tmp_path):
    """The stall limit is the tolerant rigs' 5 s, longer than the hang: only the e-stop acts,
    and it is answered done (the outputs are safe) with who wrote them."""
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:
        daemon, eps = hung_daemon(tmp_path, "sleeps_hung", 5.0, stderr)
    try:
        with Client(**eps, timeout=20.0) as client:
            events = enabled(client, daemon)
            began = hang_began(tmp_path)
            time.sleep(0.1)
            asked = time.monotonic()
            answer = client.estop("test")  # done, not loop_stalled: the loop is stuck for less than its stall limit
            assert time.monotonic() - asked < BOUND_S
            assert answer == {"state": "estop", "written_by": "watchdog"}
            schema("results", "estop").validate(answer)
            event = events.next("watchdog", limit_s=30.0)
            assert "an e-stop the loop had not taken" in event["cause"] and "sleeps_hung's step running" in event["cause"]
            assert "the cycle watchdog wrote the safe state" in event["cause"]
            replaced = events.next("controller", limit_s=30.0)  # once the step returned
            assert replaced["from"] == "sleeps_hung" and replaced["to"] == "hold"
            status = client.status()
            assert status["state"] == "estop" and status["controller"] == "hold"
            events.close()
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    record = writes(tmp_path)
    check_the_hang_wrote_safe_then_nothing_else(record, began, HANG_S)
    by_watchdog = next(t for t, thread, _ in record if thread == "cycle watchdog")
    assert asked < by_watchdog < asked + BOUND_S


class _SleepsOnce(PID):
    """PID whose 50th step sleeps ``seconds``."""

    name = "sleeps-once"
    seconds = 0.8

    def step(self, state, reference):
        self.steps = getattr(self, "steps", 0) + 1
        if self.steps == 50:
            time.sleep(self.seconds)
        return super().step(state, reference)


def _watched_loop(tmp_path, stall_s: float):
    """A loop on the real clock with its watchdog (the daemon's pair, without the daemon), and
    a list of (time, thread, volts) of every write."""
    rig = dataclasses.replace(config.load(), safety=dataclasses.replace(config.load().safety, stall_after_s=stall_s))
    loop = assembly.build_loop(rig, MonotonicClock(spin_s=0.0), 0.001, "hold")
    transport, written = loop.io.transport, []
    transport._write = lambda values, write=transport._write: (
        written.append((time.monotonic(), threading.current_thread().name, list(values))), write(values))
    loop_side, messenger_side = WatchdogLink.create(str(tmp_path)), WatchdogLink(str(tmp_path))
    loop.start()
    loop.switch(_SleepsOnce(loop.context))
    loop.enable()
    watchdog = CycleWatchdog(loop, loop_side)
    watchdog.start()
    return loop, watchdog, messenger_side, written


def test_in_process_the_watchdog_writes_safe_while_the_step_sleeps_and_the_loop_drops_the_steps_output(tmp_path):
    loop, watchdog, link, written = _watched_loop(tmp_path, 0.2)
    try:
        loop.run(60)  # the 50th step sleeps 0.8 s, four times the limit
        safe = list(loop.io.safe_volts)
        first = next(i for i, w in enumerate(written) if w[1] == "cycle watchdog")
        assert written[first][2] == safe and all(w[2] == safe for w in written[first:]), (first, link.report())
        assert written[first - 1][1] != "cycle watchdog" and written[first - 1][2] != safe
        assert written[first][0] - written[first - 1][0] < 0.2 + BOUND_S  # the limit, and the machine's slack
        report = link.report()
        assert report.count == 1 and report.cycle == 49 and report.written, report
        assert "controller sleeps-once's step has run" in report.cause, report
        assert loop.state is State.FAULT and loop.controller.name == "hold"
        assert loop.supervisor.cause.startswith("controller sleeps-once's step hung: ")
    finally:
        watchdog.stop()
        loop.shutdown()
        link.close()


def test_in_process_an_estop_poked_while_the_step_sleeps_is_written_at_once(tmp_path):
    loop, watchdog, link, written = _watched_loop(tmp_path, 5.0)  # only the e-stop acts
    try:
        poked = []
        threading.Timer(0.3, lambda: (poked.append(time.monotonic()), link.pass_estop())).start()  # during the sleep
        loop.run(60)
        by_watchdog = [w for w in written if w[1] == "cycle watchdog"]
        assert by_watchdog and poked[0] < by_watchdog[0][0] < poked[0] + BOUND_S
        assert by_watchdog[0][2] == list(loop.io.safe_volts)
        assert "an e-stop the loop had not taken" in link.report().cause
        assert loop.state is State.ESTOP and loop.controller.name == "hold"
    finally:
        watchdog.stop()
        loop.shutdown()
        link.close()


def test_in_process_an_estop_the_loop_took_before_the_watchdog_heard_it_is_not_latched_again(tmp_path):
    """On a loaded PC the FIFO's byte can reach the watchdog after the loop took the e-stop and
    was reset; the loop then late by more than the grace: nothing is written, nothing latches
    (it was latched again, after the reset, and refused the next enable)."""
    rig = dataclasses.replace(config.load(), safety=dataclasses.replace(config.load().safety, stall_after_s=5.0))
    loop = assembly.build_loop(rig, MonotonicClock(spin_s=0.0), 0.001, "hold")
    loop_side, messenger_side = WatchdogLink.create(str(tmp_path)), WatchdogLink(str(tmp_path))
    watchdog = CycleWatchdog(loop, loop_side)
    try:
        loop.start()
        loop.enable()
        loop.run(20)
        messenger_side.pass_estop()
        loop.estop("the operator")  # the loop takes it at once; the watchdog's thread has not run yet
        loop.run(5)
        loop.reset()
        loop.run(5)
        assert loop.state is State.IDLE
        watchdog.start()  # hears the byte now, then the loop does not cycle for 20 grace periods
        time.sleep(20 * watchdog.estop_grace_s)
        assert loop.held is None and loop_side.report().count == 0, loop_side.report()
        loop.run(5)
        loop.enable()
        assert loop.state is State.ENABLED
        messenger_side.pass_estop()  # and one it does not take is still written, once the grace is up
        time.sleep(20 * watchdog.estop_grace_s)
        assert loop.held is not None and "an e-stop the loop had not taken" in loop_side.report().cause
        loop.run(2)
        assert loop.state is State.ESTOP
    finally:
        watchdog.stop()
        loop.shutdown()
        loop_side.close()
        messenger_side.close()


def _reply(sock, limit_s: float = 30.0) -> dict:
    assert sock.poll(limit_s * 1e3), "no reply"
    return msgpack.unpackb(sock.recv_multipart()[-1], raw=False)


def _watchdog_event(sub, limit_s: float = 30.0) -> dict:
    deadline = time.monotonic() + limit_s
    while sub.poll(max(deadline - time.monotonic(), 0.0) * 1e3):
        event = msgpack.unpackb(sub.recv_multipart()[1], raw=False)
        if event["kind"] == "watchdog":
            return event
    raise AssertionError("no watchdog event")


@pytest.mark.slow(seconds=5)
def test_in_process_an_estop_the_late_loop_had_not_taken_is_answered_done_by_the_watchdogs_write():
    """A loop that is only late (here: not run for a moment, as a loaded PC leaves it) gets an
    e-stop it does not take within 3 periods: the watchdog writes the safe state, its event
    says how far behind its deadline the loop was, and the e-stop is answered done, written by
    the watchdog (not ``loop_stalled``); the loop latches it when it cycles. Only once the
    loop has not cycled for the messenger's stall limit is a request answered
    ``loop_stalled``, saying the watchdog wrote the safe state. The daemon's messenger, the
    loop on the real clock with its watchdog; the loop cycles only when the test runs it."""
    rig = dataclasses.replace(config.load(), safety=dataclasses.replace(config.load().safety, stall_after_s=1.0))
    srv = ZmqServer(PRIVATE, PRIVATE, PRIVATE, loop_stall_s=2.0, layout=assembly.cycle_layout(rig))
    loop = assembly.build_loop(rig, MonotonicClock(spin_s=0.0), 0.001, "hold", publish=srv.publish,
                               contact=False, stats_banks=srv.stats_banks)
    srv.attach(loop)  # a planner of its own, never started: nothing here plans
    watchdog = CycleWatchdog(loop, srv.watchdog_link)
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"event")
    sub.connect(srv.endpoints["telemetry"])
    try:
        control = dealer(srv, "control")
        time.sleep(0.3)  # the subscription reaches the publisher
        loop.start()
        loop.enable()
        watchdog.start()
        loop.run(100)
        control.send(P.encode_request("stop-1", "estop", {"who": "late"}))  # well within the stall limit (1 s)
        reply = _reply(control)  # the loop is not run: only the watchdog can have written it
        assert reply["ok"] and reply["result"] == {"state": "estop", "written_by": "watchdog"}, reply
        event = _watchdog_event(sub)
        assert "an e-stop the loop had not taken after" in event["cause"] and "behind its deadline" in event["cause"]
        assert event["cause"].endswith("the cycle watchdog wrote the safe state")
        loop.run(2)  # the loop cycles: the e-stop latches, its own reply is not sent again
        assert loop.state is State.ESTOP and "late" in loop.supervisor.cause
        assert not control.poll(200)
        # A real stall: the loop not run past the messenger's limit (2 s); the watchdog wrote
        # the safe state at the rig's 1 s
        stalled = _watchdog_event(sub)
        assert "the loop has been stuck" in stalled["cause"]
        time.sleep(1.5)
        control.send(P.encode_request("stop-2", "estop"))
        reply = _reply(control)
        assert reply["error"]["code"] == P.LOOP_STALLED and reply["error"]["data"]["safe_state_written"], reply
        schema("error-data").validate(reply["error"]["data"])
        assert "the cycle watchdog wrote the safe state" in reply["error"]["message"]
    finally:
        watchdog.stop()
        sub.close()
        loop.shutdown()
        srv.close()
