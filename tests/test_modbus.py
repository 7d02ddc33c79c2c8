"""Modbus TCP and RTU against the simulated rig served by pymodbus's own server in its own
process (python -m sim_backend.modbus_peer): tracking as in-process, a peer killed mid-move
tripping the loop with the reason, recovery after it returns and a reset, exception replies
counted, no server at start refused clearly."""
import socket

import pytest

from hal.errors import TransportError
from tests.wirehelpers import move_and_track, start_peer, stop_peer, wire_loop


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def peer(port, *args):
    return start_peer("sim_backend.modbus_peer", "--port", str(port), *args, ready=lambda: listening(port))


@pytest.mark.parametrize("framing, least_exchanges", [("tcp", 1500), ("rtu", 100)])
def test_pid_tracks_a_move_over_modbus_as_it_does_in_process(framing, least_exchanges):
    """3 s of moving. pymodbus's RTU client polls for its reply every millisecond or more,
    so an RTU exchange takes about 16 ms here (docs/benchmarks.md): fewer samples, the same
    tracking within the margin."""
    port = free_port()
    proc = peer(port, "--framer", "socket" if framing == "tcp" else "rtu")
    options = {"port": port} if framing == "tcp" else {"mode": "rtu", "device": f"socket://127.0.0.1:{port}"}
    try:
        loop, _ = wire_loop("modbus", options)
        over_wire = move_and_track(loop)
        assert loop.state.value == "enabled", loop.supervisor.cause
        health = loop.io.transport.health()
        loop.shutdown()
    finally:
        stop_peer(proc)
    in_process = move_and_track(wire_loop(None, virtual=True)[0])
    assert all(abs(w - p) < 0.5 for w, p in zip(over_wire, in_process)), (over_wire, in_process)
    assert health.counters["exchanges"] > least_exchanges and health.errors == 0, health


def test_a_killed_server_trips_the_loop_with_the_reason_and_a_new_one_recovers_after_reset():
    port = free_port()
    proc = peer(port)
    loop, _ = wire_loop("modbus", {"port": port, "reopen_every_s": 0.1})
    try:
        loop.run(200)
        loop.enable()
        loop.run(200)
        stop_peer(proc, hard=True)
        for cycles in range(1, 1000):
            loop.run(1)
            if loop.state.value == "fault":
                break
        assert loop.state.value == "fault" and "connection to 127.0.0.1" in loop.supervisor.cause, loop.supervisor.cause
        assert cycles < 100  # the connection reset is seen on the worker's next exchange
        loop.run(300)
        assert loop.state.value == "fault"
        proc = peer(port)
        for _ in range(5000):  # the worker reconnects by itself
            loop.run(1)
            if loop.io.transport.health().counters["reconnects"] >= 2:
                break
        loop.run(100)
        assert tuple(loop.io.last_volts) == tuple(loop.io.safe_volts)
        loop.reset()
        loop.enable()
        loop.run(300)
        assert loop.state.value == "enabled", loop.supervisor.cause
    finally:
        loop.shutdown()
        stop_peer(proc)


def test_exception_replies_are_counted_and_the_loop_carries_on():
    port = free_port()
    proc = peer(port, "--exception-every", "25")
    try:
        loop, _ = wire_loop("modbus", {"port": port})
        move_and_track(loop, duration_s=1.0, tail_s=0.5)
        assert loop.state.value == "enabled", loop.supervisor.cause
        health = loop.io.transport.health()
        assert health.counters["exception_replies"] >= 40 and "exception" in health.last_error
        loop.shutdown()
    finally:
        stop_peer(proc)


def test_no_server_at_start_is_a_clear_error():
    with pytest.raises(TransportError, match="cannot connect to 127.0.0.1"):
        wire_loop("modbus", {"port": free_port(), "open_timeout_s": 1.0})
