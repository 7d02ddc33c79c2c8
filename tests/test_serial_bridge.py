"""The serial DAQ bridge against the simulated rig behind a real pseudo-terminal, in its own
process (python -m sim_backend.serial_peer): tracking as in-process, a peer killed mid-move
tripping the loop to the safe state, recovery after it returns and a reset, corrupted
replies counted, a missing bridge refused at start."""
import os
import threading
import time

import pytest

from hal import config
from hal import serial_frames as F
from hal.errors import TransportError
from sim_backend.serial_peer import BridgePeer
from tests.wirehelpers import move_and_track, start_peer, stop_peer, wire_loop


def peer(link, *args):
    return start_peer("sim_backend.serial_peer", "--link", str(link), *args, ready=lambda: os.path.exists(link))


@pytest.fixture
def link(tmp_path):
    return tmp_path / "bridge"


def test_pid_tracks_a_move_over_the_serial_bridge_as_it_does_in_process(link):
    proc = peer(link)
    try:
        loop, _ = wire_loop("serial", {"port": str(link)})
        over_wire = move_and_track(loop)
        assert loop.state.value == "enabled", loop.supervisor.cause
        health = loop.io.transport.health()
        loop.shutdown()
    finally:
        stop_peer(proc)
    in_process = move_and_track(wire_loop(None, virtual=True)[0])
    assert all(abs(w - p) < 0.5 for w, p in zip(over_wire, in_process)), (over_wire, in_process)
    assert health.counters["crc_errors"] == 0 and health.reads > 2500


def test_a_killed_peer_trips_to_the_safe_state_and_a_new_one_recovers_after_reset(link):
    proc = peer(link)
    loop, captured = wire_loop("serial", {"port": str(link), "reopen_every_s": 0.1})
    try:
        loop.run(200)
        loop.enable()
        loop.run(200)
        stop_peer(proc, hard=True)  # SIGKILL: the pty's other end vanishes
        for cycles in range(1, 1000):
            loop.run(1)
            if loop.state.value == "fault":
                break
        assert loop.state.value == "fault" and "lost" in loop.supervisor.cause, loop.supervisor.cause
        assert cycles <= 2  # the next read sees the hang-up
        trips = [e for e in captured.of("event") if e.get("kind") == "state" and e.get("to") == "fault"]
        cycle = loop.cycle
        loop.run(300)  # the loop keeps its period with the wire gone (the bridge's dead-man holds the rig)
        assert loop.cycle == cycle + 300 and loop.state.value == "fault"
        proc = peer(link)
        loop.run(300)  # the transport reopens the port by itself, and the safe state goes out first
        assert tuple(loop.io.last_volts) == tuple(loop.io.safe_volts) and loop.state.value == "fault"
        loop.reset()
        loop.enable()
        loop.run(300)
        assert loop.state.value == "enabled", loop.supervisor.cause
        assert loop.io.transport.health().counters["reopened"] >= 1 and trips
    finally:
        loop.shutdown()
        stop_peer(proc)


def test_corrupted_replies_are_counted_and_the_loop_carries_on(link):
    proc = peer(link, "--corrupt-every", "20")
    try:
        loop, _ = wire_loop("serial", {"port": str(link)})
        move_and_track(loop, duration_s=1.0, tail_s=0.5)
        assert loop.state.value == "enabled", loop.supervisor.cause
        assert loop.io.transport.health().counters["crc_errors"] >= 50
        loop.shutdown()
    finally:
        stop_peer(proc)


def test_no_bridge_at_start_is_a_clear_error(link):
    with pytest.raises(TransportError, match="cannot open"):
        wire_loop("serial", {"port": str(link)})
    master, slave = os.openpty()  # a terminal is there, but nothing answers on it
    os.symlink(os.ttyname(slave), link)
    try:
        with pytest.raises(TransportError, match="no answer from the bridge"):
            wire_loop("serial", {"port": str(link), "open_timeout_s": 0.3})
    finally:
        os.close(slave)
        os.close(master)


def test_the_simulated_bridge_writes_the_safe_state_when_the_host_goes_quiet():
    """Its own dead-man, as docs/serial-bridge.md asks of a bridge: 20 ms without a frame."""
    master, slave = os.openpty()
    try:
        bridge = BridgePeer(config.load(), master)
        done = threading.Event()
        server = threading.Thread(target=bridge.serve, args=(done.is_set,))
        server.start()
        os.write(slave, F.encode(F.OUTPUTS, 1, [40000] * len(bridge.sim.outputs)))
        deadline = time.monotonic() + 2.0
        while bridge.replies == 0 and time.monotonic() < deadline:
            time.sleep(0.0005)
        driven = bridge.sim.output_volts
        time.sleep(0.1)
        quiet = bridge.sim.output_volts
        done.set()
        server.join()
        assert bridge.replies == 1 and all(abs(v - 40000 * 10 / 65535) < 1e-3 for v in driven)
        assert all(abs(q - s) < 1e-3 for q, s in zip(quiet, bridge.safe_volts))
    finally:
        os.close(slave)
        os.close(master)
