"""What a flood of requests can cost the loop's command stage, bounded whatever arrives: an
e-stop reaches the loop with a few bytes of arguments however many it carried, the stage stops
taking requests once its time budget is spent (the cycle's first request apart), and its
doorbell to the messenger never lets the GIL go (docs/benchmarks.md, "Protocol fuzz")."""
from __future__ import annotations

import ctypes
import time

import msgpack
import pytest

from daemon.loop import port
from daemon.loop.safety import State
from daemon.testing.loop import dealer, make_loop
from daemon.wire import protocol as P
from daemon.wire import routed
from daemon.wire.keys import ANONYMOUS


@pytest.fixture
def served():
    loop, _, srv = make_loop(server=True)
    loop.run(100)
    yield loop, srv
    srv.close()


def _until(condition, limit_s: float = 120.0) -> bool:
    deadline = time.monotonic() + limit_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.001)
    return condition()


def _replies(control, command, wait_ms: int) -> int:
    """The replies waiting on either socket, or coming within ``wait_ms``."""
    got = 0
    for sock in (control, command):
        while sock.poll(wait_ms):
            sock.recv_multipart()
            got += 1
    return got


def test_an_estop_reaches_the_loop_with_a_few_bytes_whatever_it_carries(served):
    """Never refused for its arguments, an e-stop may carry 60 KiB of them: the messenger passes
    on its ``who`` alone, cut to 64 characters (the loop decoded all of them, 8 a cycle: a
    cycle's command stage grew by milliseconds)."""
    loop, srv = served
    control, ring = dealer(srv, "control"), srv.rings["control"]
    junk = {f"k{i}": [1] * 4000 for i in range(14)}
    sent = [{"who": [1] * 4000, **junk}, {"who": "w" * 5000, **junk}, {"who": "panel", **junk}]
    for i, args in enumerate(sent):
        request = P.encode_request(i, "estop", args)
        assert len(request) > 50_000
        control.send(request)
    entries = []  # taken as the loop takes them
    assert _until(lambda: entries.append(ring.get()) or len([e for e in entries if e]) == len(sent))
    taken = [routed.unpack(payload)[1] for _, payload in filter(None, entries)]
    assert [len(r["payload"]) for r in taken] == [pytest.approx(120, abs=80)] * len(sent)
    assert [P.decode_args(r) for r in taken] == [{"who": repr([1] * 4000)[:64]}, {"who": "w" * 64},
                                                 {"who": "panel"}]
    control.send(P.encode_request(9, "estop", {"who": "the test", **junk}))
    assert _until(ring.pending)
    loop.run(1)
    assert loop.state is State.ESTOP and loop.supervisor.cause == "e-stop from the test"
    assert msgpack.unpackb(control.recv_multipart()[-1])["ok"]


def test_the_command_stage_stops_at_its_budget_after_the_cycles_first_request(served):
    """With no time to spare (a budget of 0), each cycle serves one request, control first;
    with time, eight control and two command requests (the virtual clock never spends it)."""
    loop, srv = served
    control, command = dealer(srv, "control"), dealer(srv, "command")
    for budget, per_cycle in ((0.0, [1] * 14), (port.COMMAND_BUDGET_S, [8 + 2, 2 + 2])):
        srv.command_budget_s = budget
        requests = {"control": [P.encode_request(i, "status") for i in range(10)],
                    "command": [P.encode_request(100 + i, "ping") for i in range(4)]}
        for name, sock in (("control", control), ("command", command)):
            for request in requests[name]:
                sock.send(request)
            queued = sum(12 + len(routed.pack(ANONYMOUS, P.decode_request(r))) for r in requests[name])
            ring = srv.rings[name]
            assert _until(lambda: ring.capacity - ring.free() == queued), name  # all in the loop's rings
        answered = []
        for expected in per_cycle:
            loop.run(1)
            got, deadline = 0, time.monotonic() + 60.0
            while got < expected and time.monotonic() < deadline:  # this cycle's replies, however slow
                got += _replies(control, command, 50)
            answered.append(got + _replies(control, command, 20))  # and any beyond (or in the next cycle's count)
        assert answered == per_cycle, (budget, answered)


def test_the_doorbell_to_the_messenger_keeps_the_gil():
    """os.write lets the GIL go for the call: the planner's courier thread (normal priority) can
    take it, and the loop waits until that thread is scheduled again to give it back (8-69 ms
    on a loaded machine, a stall trip). The doorbell is written by a foreign function that keeps
    the GIL (ctypes.PyDLL)."""
    assert port._WRITE._flags_ & ctypes._FUNCFLAG_PYTHONAPI
    assert port._WRITE.__name__ == "write"
