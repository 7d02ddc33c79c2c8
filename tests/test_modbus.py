"""Modbus TCP and RTU against the simulated rig served by pymodbus's own server in its own
process (python -m sim_backend.modbus_peer): tracking as in-process, a peer killed mid-move
tripping the loop with the reason, recovery after it returns and a reset, exception replies
counted, no server at start refused clearly."""
import os
import signal
import subprocess
import sys
import time

import pytest
from pymodbus.client import ModbusTcpClient

from bench.wires import listening
from daemon.client.client import Client, RemoteError
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.ports import free_tcp_port
from hal import config
from hal.errors import TransportError
from hal.transport import create_transport, volts_to_counts
from tests.daemons import real_daemon, running, wait_for_own_daemon
from tests.wirehelpers import (
    move_and_track,
    start_peer,
    stop_peer,
    tracks_like_in_process,
    trip_and_recover,
    wire_loop,
)


def peer(port, *args):
    return start_peer("sim_backend.modbus_peer", "--port", str(port), *args, ready=lambda: listening(port))


@pytest.mark.slow
@pytest.mark.parametrize("framing, least_exchanges", [("tcp", 1500), ("rtu", 100)])
def test_pid_tracks_a_move_over_modbus_as_it_does_in_process(framing, least_exchanges):
    """3 s of moving. pymodbus's RTU client polls for its reply every millisecond or more,
    so an RTU exchange takes about 16 ms here (docs/benchmarks.md): fewer samples, the same
    tracking within the margin."""
    port = free_tcp_port()
    proc = peer(port, "--framer", "socket" if framing == "tcp" else "rtu")
    # One transaction may take hundreds of ms when this machine is busy (beside two CPU hogs an
    # RTU reply took more than 150 ms): waited for up to RELAXED's stale limit (tests/wirehelpers.py),
    # 1 s, against the rig's 50 ms. What is checked is the tracking and that nothing was lost.
    options = {"port": port} if framing == "tcp" else {"mode": "rtu", "device": f"socket://127.0.0.1:{port}"}
    options["timeout_s"] = 1.0
    try:
        health = tracks_like_in_process(wire_loop("modbus", options)[0])
    finally:
        stop_peer(proc)
    assert health.counters["exchanges"] > least_exchanges and health.errors == 0, health


@pytest.mark.slow(seconds=4)  # a few seconds: kept out of the fast subset
def test_a_killed_server_trips_the_loop_with_the_reason_and_a_new_one_recovers_after_reset():
    port = free_tcp_port()
    peers = [peer(port)]
    # a transaction may take 150 ms on a busy machine (as the tracking test above allows)
    loop, _ = wire_loop("modbus", {"port": port, "reopen_every_s": 0.1, "timeout_s": 0.15})
    try:
        cycles, cause = trip_and_recover(loop, lambda: stop_peer(peers[-1], hard=True),
                                         lambda: peers.append(peer(port)),
                                         lambda: loop.io.transport.health().counters["reconnects"] >= 2)
        assert "connection to 127.0.0.1" in cause and "lost" in cause, cause
        # the connection reset is seen on the worker's next exchange (the cause says so); the
        # count is bounded generously, as a busy machine may hold the worker for a while
        assert cycles < 1000
    finally:
        loop.shutdown()
        stop_peer(peers[-1])


@pytest.mark.slow(seconds=3)  # a few seconds: kept out of the fast subset
def test_exception_replies_are_counted_and_the_loop_carries_on():
    port = free_tcp_port()
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


@pytest.mark.slow(seconds=5)  # a few seconds: kept out of the fast subset
def test_no_server_at_start_is_a_clear_error():
    # The worker retries until the open limit and the error carries its last reason: the limit
    # leaves a busy machine time to start the worker and have its connect refused (two CPU
    # hogs took more than 1 s to start it).
    with pytest.raises(TransportError, match="cannot connect to 127.0.0.1"):
        wire_loop("modbus", {"port": free_tcp_port(), "open_timeout_s": 5.0})


@pytest.mark.slow  # long: kept out of the fast subset
def test_the_dead_man_command_writes_the_safe_state_through_modbus():
    """``pneumad safe-state`` (systemd's stop hook) over Modbus: a fresh process, its own
    exchange worker, and the safe outputs in the module's registers when it exits."""
    port = free_tcp_port()
    proc = peer(port)
    try:
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=1.0)
        client.connect()
        client.write_registers(100, [30000] * 4, device_id=1)  # outputs driven somewhere
        out = subprocess.run([sys.executable, "-m", "daemon.main", "safe-state", "--transport", "modbus",  # a busy
                              "--transport-option", f"port={port}", "--transport-option", "open_timeout_s=60"],  # start
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0 and "safe state written" in out.stdout, out.stderr
        assert client.read_holding_registers(100, count=4, device_id=1).registers == [0, 0, 0, 0]
        client.close()
    finally:
        stop_peer(proc)


@pytest.mark.slow(seconds=5)
def test_from_its_first_exchange_the_worker_writes_the_rigs_safe_state_not_zero_volts():
    """Before the loop writes anything, the Modbus worker's exchanges carry the rig's safe
    state: on the linear axis, 0 V would drive its 5/3 valve fully open, the piston to its end
    stop; its safe state is the valve's null (4.99 V)."""
    port = free_tcp_port()
    proc = start_peer("sim_backend.modbus_peer", "--config", "sim-axis", "--port", str(port),
                      ready=lambda: listening(port))
    rig = config.with_transport(config.load("sim-axis"), "modbus", {"port": port, "open_timeout_s": 60.0})
    transport = create_transport(rig, time.monotonic)
    try:
        transport.open()  # it waits for the first exchange
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=5.0)
        client.connect()
        assert client.read_holding_registers(100, count=1, device_id=1).registers == \
            volts_to_counts([4.99], transport.outputs)
        client.close()
    finally:
        transport.close()
        stop_peer(proc)


HOLDER = """
import sys, time
from hal import config
from hal.transport import create_transport
rig = config.with_transport(config.load(), "modbus", {"port": int(sys.argv[1])})
transport = create_transport(rig, time.monotonic)
transport.open()
transport.write([6.0] * len(transport.outputs))
print(transport._process.pid, flush=True)
time.sleep(600)
"""


@pytest.mark.slow
def test_a_daemon_killed_hard_leaves_no_worker_writing_over_the_dead_man():
    """SIGKILL the process that owns a Modbus transport: its exchange worker goes with it,
    so the safe state the dead-man command writes afterwards stays written."""
    port = free_tcp_port()
    proc = peer(port)
    try:
        holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(port)], stdout=subprocess.PIPE, text=True)
        worker = int(holder.stdout.readline())
        holder.kill()
        holder.wait(STOP_WAIT_S)
        out = subprocess.run([sys.executable, "-m", "daemon.main", "safe-state", "--transport", "modbus",  # a busy
                              "--transport-option", f"port={port}", "--transport-option", "open_timeout_s=60"],  # start
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        time.sleep(0.3)  # an orphaned worker would have written its outputs again by now
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=1.0)
        client.connect()
        assert client.read_holding_registers(100, count=4, device_id=1).registers == [0, 0, 0, 0]
        client.close()
        end = time.monotonic() + 30.0  # it went with its owner; its reaping by init may come late
        while running(worker) and time.monotonic() < end:
            time.sleep(0.05)
        assert not running(worker)
    finally:
        stop_peer(proc)


def test_a_transport_dropped_without_close_takes_its_worker_with_it():
    """The cause of a soak failure (issue 19): a test that failed mid-move left its Modbus
    worker running; it went on writing its link errors into shared memory the next test's
    transport was then given, and that test tripped on another test's connection. A
    transport that is dropped unclosed now stops its worker."""
    import gc

    from hal import config
    from hal.transport import create_transport
    port = free_tcp_port()
    proc = peer(port)
    try:
        rig = config.with_transport(config.load(), "modbus", {"port": port})
        transport = create_transport(rig, time.monotonic)
        transport.open()
        worker = transport._process.pid
        del transport
        gc.collect()
        end = time.monotonic() + 30.0  # its end is waited for: a busy machine schedules it late
        while running(worker) and time.monotonic() < end:
            time.sleep(0.05)
        assert not running(worker)
    finally:
        stop_peer(proc)



@pytest.mark.slow(seconds=30)
def test_a_killed_exchange_worker_is_an_event_a_log_line_and_restarted_and_the_arm_comes_back_after_reset(tmp_path):
    """In a real daemon over Modbus, the exchange worker process killed with the arm enabled:
    no new sample, so a trip; the loop's next look starts another (an ``exchange`` event, a
    line in the daemon's log, ``helpers.exchange``), which reconnects; ``reset`` and
    ``enable`` work again."""
    port = free_tcp_port()
    proc = peer(port)
    log = tmp_path / "daemon.log"
    try:
        with open(log, "w") as stderr:
            daemon, eps = real_daemon(tmp_path, "--transport", "modbus", "--transport-option", f"port={port}",
                                      "--transport-option", "open_timeout_s=60", "--transport-option", "timeout_s=0.5",
                                      "--safety", "stale_after_s=1.0",
                                      stderr=stderr)  # (relaxed limits, as the wire tests': a loaded machine's Modbus)
        try:
            with Client(**eps, timeout=10.0) as client:
                wait_for_own_daemon(client, daemon)
                sub = client.subscribe((b"event",))
                sub.wait_until_heard()
                before = client.status()["helpers"]["exchange"]
                assert before["running"] and before["restarts"] == 0
                client.acquire_lease()
                client.keep_lease()
                client.enable()
                os.kill(before["pid"], signal.SIGKILL)
                kinds, end = {}, time.monotonic() + 60.0
                while not {"trip", "exchange"} <= set(kinds):
                    assert time.monotonic() < end, kinds
                    got = sub.receive(1.0)
                    if got is not None:
                        kinds.setdefault(got[1]["kind"], got[1])
                assert "exited (code -9) and was restarted (restart 1)" in kinds["exchange"]["cause"]
                assert "modbus" in kinds["trip"]["cause"] or "stale" in kinds["trip"]["cause"], kinds["trip"]
                end = time.monotonic() + 60.0  # the new worker connected and exchanging, however slow
                while not (after := client.status()["helpers"]["exchange"])["running"]:
                    assert time.monotonic() < end, after
                    time.sleep(0.2)
                assert after["restarts"] == 1 and after["pid"] != before["pid"] and after["last_exit_code"] == -9
                status = {"cause": "never reset"}
                while True:  # fresh samples end the stale input (reset is refused until then), and stay
                    try:
                        client.reset()
                        client.enable()
                        time.sleep(0.5)
                        if (status := client.status())["state"] == "enabled":
                            break
                    except RemoteError:
                        pass
                    assert time.monotonic() < end, status["cause"]
                    time.sleep(0.2)
                sub.close()
        finally:
            daemon.terminate()
            daemon.wait(STOP_WAIT_S)
    finally:
        stop_peer(proc)
    assert "pneumad messenger ERROR: exchange: the modbus exchange worker exited (code -9) and was restarted " \
           "(restart 1)" in log.read_text()
