"""An arm left enabled with nobody holding the lease: the rig file's policy, on the real loop
(virtual clock) over real sockets; and pneumactl's one-shot lease against a real daemon."""
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import pytest

from daemon.client.client import Client
from daemon.recordings import mcap_log
from daemon.loop.commands import Commands
from daemon.loop.safety import State
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.loop import call, dealer, make_loop, ok, run_seconds, shared_preparer
from daemon.wire import protocol as P
from daemon.wire.keys import OPERATOR, Identity
from tests.daemons import endpoint_env, real_daemon, wait_for_own_daemon

RIG = (Path(__file__).resolve().parents[1] / "hal" / "sim_2joint.toml").read_text()


def rig(action: str, grace_s: float) -> str:
    text = RIG.replace('unleased_action = "disable"', f'unleased_action = "{action}"')
    return text.replace("unleased_grace_s = 60.0", f"unleased_grace_s = {grace_s}")


@pytest.fixture
def enabled_then_released(request):
    """An arm enabled by a client that then handed the lease back (as ``pneumactl enable``)."""
    loop, captured, srv = make_loop(rig(*request.param), server=True)
    sock = dealer(srv)
    lease = ok(loop, sock, "lease.acquire")["lease"]
    ok(loop, sock, "enable", lease=lease)
    released = ok(loop, sock, "lease.release", lease=lease)
    yield loop, captured, sock, released
    srv.close()


@pytest.mark.parametrize("enabled_then_released", [("disable", 2.0)], indirect=True)
def test_an_unleased_arm_holds_for_the_grace_time_then_is_disabled_to_the_safe_state(enabled_then_released):
    loop, captured, sock, released = enabled_then_released
    assert released["unleased"]["action"] == "disable" and "2 s" in released["unleased"]["note"]
    run_seconds(loop, 1.0)
    status = ok(loop, sock, "status")
    assert status["state"] == "enabled" and 0.5 < status["unleased_disable_in_s"] < 1.5
    run_seconds(loop, 1.5)
    assert loop.state is State.IDLE
    assert list(loop.io.transport.output_volts) == pytest.approx(list(loop.io.safe_volts), abs=1e-3)
    loop.telemetry.flush()
    kinds = [e["kind"] for e in captured.of("event")]
    assert "unleased" in kinds and ok(loop, sock, "status")["unleased_disable_in_s"] is None


@pytest.mark.parametrize("enabled_then_released", [("disable", 2.0)], indirect=True)
def test_a_reference_runs_to_its_end_before_the_grace_time_starts(enabled_then_released):
    loop, _, sock, _ = enabled_then_released
    lease = ok(loop, sock, "lease.acquire")["lease"]
    ok(loop, sock, "set", {"angles_deg": [130.0, -90.0], "duration_s": 4.0}, lease)
    ok(loop, sock, "lease.release", lease=lease)
    run_seconds(loop, 3.5)
    assert loop.state is State.ENABLED and ok(loop, sock, "status")["unleased_disable_in_s"] is None
    run_seconds(loop, 2.0)  # the move ended at 4 s: 1.5 s of holding so far
    assert loop.state is State.ENABLED
    run_seconds(loop, 1.0)
    assert loop.state is State.IDLE


@pytest.mark.parametrize("enabled_then_released", [("disable", 2.0)], indirect=True)
def test_a_client_taking_the_lease_in_the_grace_time_keeps_the_arm(enabled_then_released):
    loop, _, sock, _ = enabled_then_released
    run_seconds(loop, 1.5)
    lease = ok(loop, sock, "lease.acquire", {"ttl_s": 10.0})["lease"]
    run_seconds(loop, 3.0)
    assert loop.state is State.ENABLED
    ok(loop, sock, "lease.release", lease=lease)  # and a fresh grace time from here
    run_seconds(loop, 1.5)
    assert loop.state is State.ENABLED
    run_seconds(loop, 1.0)
    assert loop.state is State.IDLE


@pytest.mark.parametrize("enabled_then_released", [("hold", 1.0)], indirect=True)
def test_the_hold_policy_keeps_an_unleased_arm_enabled(enabled_then_released):
    loop, _, sock, released = enabled_then_released
    assert released["unleased"]["action"] == "hold"
    run_seconds(loop, 3.0)
    assert loop.state is State.ENABLED and ok(loop, sock, "status")["unleased_disable_in_s"] is None


def test_under_the_hold_policy_an_arm_whose_lease_holders_key_was_revoked_holds_on():
    """A revoked key's lease ends (``lease.revoke``, the messenger's at a reload, handled here
    as the loop's port hands it on; tests/test_revocation.py runs it on a real daemon): with
    ``unleased_action = "hold"`` the arm holds, enabled, and no grace time runs."""
    loop, captured, _ = make_loop(rig("hold", 1.0))
    commands = Commands(loop, shared_preparer())

    def handle(who: str, cmd: str, args=None, lease=None) -> dict:
        request = P.decode_request(P.encode_request(1, cmd, args, lease))
        reply = msgpack.unpackb(commands.handle_request(request, False, Identity(who, OPERATOR)), raw=False)
        assert reply["ok"], reply
        return reply["result"]

    lease = handle("ann", "lease.acquire")["lease"]
    handle("ann", "enable", lease=lease)
    assert handle("bea", "lease.revoke", {"key": "bob"}) == {"ended": False, "cause": ""}  # not the holder
    assert handle("bea", "lease.revoke", {"key": "ann"})["ended"]
    loop.run(1)
    run_seconds(loop, 3.0)
    status = handle("bea", "status")
    assert status["state"] == "enabled" and not status["lease_held"] and status["unleased_disable_in_s"] is None
    loop.telemetry.flush()
    revoked = [e for e in captured.of("event") if e["kind"] == "lease_revoked"]
    assert len(revoked) == 1 and revoked[0]["key"] == "ann" and revoked[0]["who"] == "bea"
    assert 'unleased_action = "hold"' in revoked[0]["cause"]


@pytest.mark.parametrize("enabled_then_released", [("disable", 60.0)], indirect=True)
def test_the_unleased_note_is_first_once_an_enabled_period(enabled_then_released):
    loop, _, sock, released = enabled_then_released
    assert released["unleased"]["first"]
    for _ in range(2):  # one-shot commands after it: each hands the lease back, and is told again, not first
        lease = ok(loop, sock, "lease.acquire")["lease"]
        assert not ok(loop, sock, "lease.release", lease=lease)["unleased"]["first"]
    lease = ok(loop, sock, "lease.acquire")["lease"]
    ok(loop, sock, "disable", lease=lease)
    ok(loop, sock, "enable", lease=lease)
    assert ok(loop, sock, "lease.release", lease=lease)["unleased"]["first"]  # a new enabled period


def test_a_refused_lease_says_who_holds_it_and_whether_they_keep_renewing_it():
    loop, _, srv = make_loop(server=True)
    try:
        holder, other = dealer(srv), dealer(srv)
        lease = ok(loop, holder, "lease.acquire", {"ttl_s": 2.0})["lease"]
        refused = call(loop, other, "lease.acquire")
        assert refused["error"]["code"] == "lease_held" and "unless they renew it" in refused["error"]["message"]
        run_seconds(loop, 1.5)
        ok(loop, holder, "lease.renew", lease=lease)
        run_seconds(loop, 0.5)
        message = call(loop, other, "lease.acquire")["error"]["message"]
        assert "keeps renewing it (last 0.5 s ago, 1 renewal so far)" in message and "2 s" in message, message
    finally:
        srv.close()


def test_releasing_the_lease_of_an_idle_arm_says_nothing_more():
    loop, _, srv = make_loop(server=True)
    try:
        sock = dealer(srv)
        lease = ok(loop, sock, "lease.acquire")["lease"]
        assert ok(loop, sock, "lease.release", lease=lease) == {}
    finally:
        srv.close()


@pytest.mark.slow(seconds=16)
def test_a_one_shot_pneumactl_command_keeps_the_lease_while_its_work_outlasts_it(tmp_path):
    """pneumactl's one-shot commands renew the lease they took until they hand it back: a
    controller build slower than the one-shot lease (10 s) ends with the build's own answer,
    the enabled arm is not tripped by a lapsed lease, and the lease is handed back."""
    daemon, eps = real_daemon(tmp_path, "--controller-plugin", "slow_to_build=tests.plugins:SlowToBuild")
    env = endpoint_env(eps)

    def pneumactl(*args):
        return subprocess.run([sys.executable, "-m", "daemon.client.ctl", *args], env=env, capture_output=True,
                              text=True, timeout=300)
    try:
        with Client(**eps, timeout=5.0) as client:
            wait_for_own_daemon(client, daemon)
            assert pneumactl("enable").returncode == 0
            done = pneumactl("controller", "switch", "slow_to_build")
            assert done.returncode == 1 and "took its time, and refuses" in done.stderr, done.stderr
            status = client.status()
            assert status["state"] == "enabled" and status["trips"] == 0, status["cause"]
            assert not status["lease_held"]  # handed back
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


def lease_events(sub, limit_s: float = 1.0) -> list[dict]:
    """The ``lease`` and ``trip`` events received so far."""
    got = []
    while (item := sub.receive(limit_s)) is not None:
        if item[0] == "event" and item[1]["kind"] in ("lease", "trip"):
            got.append(item[1])
    return got


@pytest.mark.slow(seconds=20)
def test_a_pause_of_the_loop_longer_than_the_lease_is_not_its_holders_silence(tmp_path):
    """The loop process stopped (SIGSTOP) for longer than the lease's ttl while its holder
    renews all along: the renewals wait in the rings, the pause is not counted against the
    lease, and the enabled arm is not tripped "lease lost" when the loop cycles again."""
    daemon, eps = real_daemon(tmp_path)  # its stall limit is 5 s: a 3 s pause trips nothing by itself
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            sub = client.subscribe((b"event",))
            sub.wait_until_heard()
            ttl = client.acquire_lease()["ttl_s"]
            client.keep_lease()
            client.enable()
            os.kill(daemon.pid, signal.SIGSTOP)  # the loop's own process: its helpers run on
            try:
                time.sleep(1.5 * ttl)
            finally:
                os.kill(daemon.pid, signal.SIGCONT)
            time.sleep(2.0 * ttl)  # renewed since, or lapsed by now
            status = client.status()
            events = lease_events(sub)
            assert status["state"] == "enabled" and status["lease_held"], (status["cause"], events)
            assert [e["action"] for e in events if e["kind"] == "lease"] == ["acquire"], events
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


HOG = "while True: pass"


@pytest.mark.slow(seconds=40)
def test_a_client_keeps_its_lease_while_it_records_and_fits_beside_two_cpu_hogs(tmp_path):
    """A client that records the telemetry in a thread (as ``pneumactl identify`` does) and fits
    in its main thread (pure Python, holding the GIL) keeps the lease its renewal thread renews,
    with two busy-loop processes taking the machine's CPUs: no lease lapses. (The loop, with no
    real-time scheduling, may be held off the CPU meanwhile; a trip for that is the machine's, and
    is never "lease lost".)"""
    daemon, eps = real_daemon(tmp_path)
    hogs = []
    try:
        with Client(**eps, timeout=20.0) as client, Client(**eps, timeout=20.0) as listener:
            wait_for_own_daemon(client, daemon)
            sub = client.subscribe((b"event",))
            sub.wait_until_heard()
            client.acquire_lease()
            client.keep_lease()
            client.enable()
            hogs = [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(2)]
            stop = threading.Event()
            recorder = threading.Thread(target=mcap_log.record,
                                        args=(listener, str(tmp_path / "run.mcap"), math.inf, None, stop))
            recorder.start()
            try:
                fit_until, x = time.monotonic() + 15.0, 0.0
                while time.monotonic() < fit_until:  # the fit: pure Python, the GIL held between checks
                    x += sum(math.sin(i) for i in range(200_000))
            finally:
                stop.set()
                recorder.join(30.0)
            for hog in hogs:
                hog.kill()
            status = client.status()
            events = lease_events(sub)
            assert status["lease_held"], (status["cause"], events)
            assert not [e for e in events if e["kind"] == "lease" and e["action"] == "expire"], events
            assert not [e for e in events if "lease" in e.get("cause", "")], events
            assert mcap_log.read(tmp_path / "run.mcap").messages["state"]  # it did record meanwhile
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
