"""A loop that is late anyway: a cycle that runs too long trips and writes the safe state at
once, and while the loop does not cycle the messenger answers for it (``loop_stalled``) and
says so on telemetry, so no client waits in silence and nothing it was refused runs later.
(That planning never runs in the loop's process is tests/test_every_command.py's.)"""
import dataclasses
import time

import msgpack
import zmq

from controllers.pid import PID
from daemon import assembly
from daemon.wire import protocol as P
from daemon.loop.clock import MonotonicClock
from daemon.loop.safety import State
from hal import config
from daemon.testing.loop import call, dealer, make_loop, ok


class SleepsOnce(PID):
    """PID that holds its cycle for 0.6 s once, on its 50th step (a stand-in for any long cycle)."""

    name = "sleeps-once"

    def step(self, state, reference):
        self.steps = getattr(self, "steps", 0) + 1
        if self.steps == 50:
            time.sleep(0.6)
        return super().step(state, reference)


def test_a_cycle_that_runs_past_the_stall_limit_trips_and_writes_the_safe_state_at_once():
    # A 0.3 s stall limit (the rig file's is 50 ms): this machine's own stalls, tens of ms,
    # must not be what trips it; the slow cycle is twice the limit.
    rig = dataclasses.replace(config.load(), safety=dataclasses.replace(config.load().safety, stall_after_s=0.3))
    clock = MonotonicClock(spin_s=0.0)
    loop = assembly.build_loop(rig, clock, 0.001, "hold")
    transport = loop.io.transport
    loop.start()
    loop.switch(SleepsOnce(loop.context))
    loop.enable()
    loop.run(49)  # the 50th control step sleeps; the loop woke on time for it
    assert loop.state is State.ENABLED
    written = []
    transport._write = lambda values, write=transport._write: (written.append(list(values)), write(values))
    loop.run(1)
    assert loop.state is State.FAULT and "a cycle ran" in loop.supervisor.cause
    assert written[-1] == list(loop.io.safe_volts)  # in that same cycle, not the next
    transport.close()


def test_while_the_loop_does_not_cycle_the_messenger_answers_for_it_and_refused_requests_never_run():
    loop, _, srv = make_loop(server=True, loop_stall_s=0.5)  # the daemon's own setting
    try:
        command, control = dealer(srv), dealer(srv, "control")
        sub = zmq.Context.instance().socket(zmq.SUB)
        sub.setsockopt(zmq.LINGER, 0)
        sub.setsockopt(zmq.SUBSCRIBE, b"event")
        sub.connect(srv.endpoints["telemetry"])
        lease = ok(loop, command, "lease.acquire", {"ttl_s": 60.0})["lease"]
        ok(loop, command, "enable", lease=lease)
        loop.run(100)
        time.sleep(0.2)  # the subscription reaches the publisher
        # The loop now stops cycling (a virtual clock moves only when it runs).
        time.sleep(0.8)
        command.send(P.encode_request("move-1", "set", {"angles_deg": [130.0, -75.0]}, lease))
        control.send(P.encode_request("stop-1", "estop"))
        replies = {}
        for sock in (command, control):
            assert sock.poll(2000), "no answer while the loop is stalled"
            reply = msgpack.unpackb(sock.recv_multipart()[-1], raw=False)
            replies[reply["id"]] = reply
        assert {k: r["error"]["code"] for k, r in replies.items()} == {"move-1": P.LOOP_STALLED,
                                                                       "stop-1": P.LOOP_STALLED}
        assert "nothing was done" in replies["move-1"]["error"]["message"]
        assert "takes effect if the loop resumes" in replies["stop-1"]["error"]["message"]
        assert replies["stop-1"]["error"]["data"]["stalled_s"] >= 0.5
        events = []
        while sub.poll(1000):
            events.append(msgpack.unpackb(sub.recv_multipart()[1], raw=False))
            if events[-1]["kind"] == "loop_stalled":
                break
        assert events and events[-1]["kind"] == "loop_stalled" and events[-1]["source"] == "messenger"
        stalled_seq = events[-1]["seq"]
        # The loop resumes: the queued e-stop takes effect, the refused move never starts.
        kinds, seqs = [], []
        for _ in range(300):
            loop.run(1)
            while sub.poll(1):
                event = msgpack.unpackb(sub.recv_multipart()[1], raw=False)
                kinds.append(event["kind"])
                seqs.append(event["seq"])
        assert loop.state is State.ESTOP and loop.trajectory_name == "hold"
        assert not command.poll(0)  # the refused request got no second reply
        assert "loop_resumed" in kinds and "estop" in kinds
        assert seqs == list(range(stalled_seq + 1, stalled_seq + 1 + len(seqs)))  # one sequence, no gap
        assert call(loop, command, "ping")["ok"]
    finally:
        srv.close()
