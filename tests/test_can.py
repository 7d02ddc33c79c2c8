"""CAN against the simulated rig as a CAN node: on python-can's virtual bus in this process,
and on its UDP-multicast bus with the node in its own process (python -m
sim_backend.can_peer): tracking as in-process, a node killed mid-move tripping the loop on
stale input, recovery after it returns and a reset, stray and short frames counted."""
import random
import threading

import can
import pytest

from hal import config
from hal.errors import TransportError
from sim_backend.can_peer import CanPeer
from tests.wirehelpers import (
    RELAXED,
    move_and_track,
    private_bus,
    start_peer,
    stop_peer,
    tracks_like_in_process,
    trip_and_recover,
    wire_loop,
)


def node(bus, *args):
    # ready when the host's open() gets its answer: open_timeout_s covers the node's start-up
    return start_peer("sim_backend.can_peer", "--interface", "udp_multicast", "--channel", bus[0],
                      "--port", str(bus[1]), *args, ready=lambda: True)


def multicast(bus, **more):
    return {"interface": "udp_multicast", "channel": bus[0], "port": bus[1], "open_timeout_s": 20.0, **more}


@pytest.mark.slow
def test_pid_tracks_a_move_over_the_virtual_bus_in_process():
    channel = f"pneumad-{random.random()}"
    bus = can.Bus(interface="virtual", channel=channel)
    peer = CanPeer(config.load(), bus)
    done = threading.Event()
    server = threading.Thread(target=peer.serve, args=(done.is_set,))
    server.start()
    try:
        tracks_like_in_process(wire_loop("can", {"interface": "virtual", "channel": channel})[0])
    finally:
        done.set()
        server.join()
        bus.shutdown()


@pytest.mark.slow
def test_pid_tracks_a_move_over_udp_multicast_with_the_node_in_its_own_process():
    bus = private_bus()
    proc = node(bus)
    try:
        health = tracks_like_in_process(wire_loop("can", multicast(bus))[0])
    finally:
        stop_peer(proc)
    assert health.counters["wrong_ids"] == 0 and health.counters["bad_lengths"] == 0


@pytest.mark.slow  # long: kept out of the fast subset
def test_a_killed_node_trips_the_loop_on_stale_input_and_a_new_one_recovers_after_reset():
    bus = private_bus()
    nodes = [node(bus)]
    loop, _ = wire_loop("can", multicast(bus))
    try:
        cycles, cause = trip_and_recover(loop, lambda: stop_peer(nodes[-1], hard=True),
                                         lambda: nodes.append(node(bus)),
                                         lambda: loop.clock.now() - loop.snapshot.t < 0.005)
        # the stale limit (RELAXED's) and a few cycles
        assert "stale" in cause and cycles <= RELAXED["stale_after_s"] * 1000 + 20, (cycles, cause)
    finally:
        loop.shutdown()
        stop_peer(nodes[-1])


@pytest.mark.slow(seconds=3)  # a few seconds: kept out of the fast subset
def test_stray_ids_and_short_frames_are_counted_and_the_loop_carries_on():
    bus = private_bus()
    proc = node(bus, "--wrong-id-every", "10", "--short-frame-every", "7")
    try:
        loop, _ = wire_loop("can", multicast(bus))
        move_and_track(loop, duration_s=1.0, tail_s=0.5)
        assert loop.state.value == "enabled", loop.supervisor.cause
        counters = loop.io.transport.health().counters
        assert counters["wrong_ids"] >= 100 and counters["bad_lengths"] >= 140, counters
        loop.shutdown()
    finally:
        stop_peer(proc)


def test_no_node_at_start_is_a_clear_error():
    with pytest.raises(TransportError, match="no answer on udp_multicast"):
        wire_loop("can", multicast(private_bus(), open_timeout_s=0.5))
