"""CURVE keys end to end on a real daemon over real sockets: who may connect, who may take
the lease, what a revoked key gets, and the refusal to bind past loopback without keys."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
import zmq

from daemon.testing.daemons import STOP_WAIT_S
from daemon.wire import keys, routed
from daemon.wire import protocol as P
from daemon.client.client import Client, KeyRefused, RemoteError
from tests.daemons import free_tcp_ports, real_daemon

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """A daemon with keys: alice (operator) and bob (observer) made on its PC, carol's made
    on her own machine and allowed from her public file."""
    root = tmp_path_factory.mktemp("keys")
    server_dir, handed, own = root / "server", root / "handed", root / "carol"
    handed.mkdir()
    keys.init_server(str(server_dir))
    alice = keys.make_client(str(server_dir), "alice", keys.OPERATOR, str(handed))
    bob = keys.make_client(str(server_dir), "bob", keys.OBSERVER, str(handed))
    carol_public, carol = keys.new_client_pair(str(own), "carol")
    keys.allow(str(server_dir), "carol", keys.OPERATOR, keys.read_key_pair(carol_public, need_secret=False)[0])
    proc, eps = real_daemon(root, "--keys", str(server_dir))
    files = {"alice": alice, "bob": bob, "carol": carol, "server": str(server_dir / keys.SERVER_PUBLIC),
             "dir": str(server_dir)}
    try:
        with Client(**eps, timeout=10.0, key_file=alice) as c:
            c.call("ping", timeout=60.0)
        yield proc, eps, files
    finally:
        proc.terminate()
        proc.wait(STOP_WAIT_S)


def client(eps, key_file=None, server_key_file=None, timeout=3.0) -> Client:
    return Client(**eps, timeout=timeout, key_file=key_file, server_key_file=server_key_file)


def test_an_allowed_key_is_known_by_its_name_and_the_daemon_says_it_checks_keys(lab):
    _, eps, files = lab
    with client(eps, files["alice"]) as alice:
        status = alice.status()
        assert status["client"] == {"name": "alice", "role": "operator"}
        assert status["security"] == {"mode": "curve", "warning": None}
        assert alice.describe()["security"]["mode"] == "curve"
    with client(eps, files["carol"], files["server"]) as carol:  # her own pair, the daemon's public key apart
        assert carol.status()["client"]["name"] == "carol"


def test_a_client_without_a_key_or_with_an_unknown_one_is_refused_with_a_clear_error(lab, tmp_path):
    _, eps, files = lab
    with client(eps, timeout=1.0) as nobody, pytest.raises(KeyRefused, match="wants a key"):
        nobody.status()
    _, stranger = keys.new_client_pair(str(tmp_path), "mallory", files["server"])
    with client(eps, stranger, timeout=1.0) as mallory, pytest.raises(KeyRefused, match="refused the key"):
        mallory.call("lease.acquire")
    # Telemetry too: a subscriber without a key hears nothing, one with a key hears the stream.
    bare = zmq.Context.instance().socket(zmq.SUB)
    bare.setsockopt(zmq.LINGER, 0)
    bare.setsockopt(zmq.SUBSCRIBE, b"")
    bare.connect(eps["telemetry"])
    with client(eps, files["bob"]) as bob:
        sub = bob.subscribe((b"state",))
        try:
            assert sub.receive(5.0) is not None
            assert not bare.poll(500)
        finally:
            sub.close()
            bare.close()


def test_an_observer_reads_and_may_estop_but_never_takes_the_lease(lab):
    _, eps, files = lab
    with client(eps, files["bob"]) as bob, client(eps, files["alice"]) as alice:
        assert bob.status()["client"]["role"] == "observer"
        with pytest.raises(RemoteError) as refused:
            bob.acquire_lease()
        assert refused.value.code == P.FORBIDDEN and refused.value.data == {"reason": "role", "role": "observer"}
        with pytest.raises(RemoteError) as reload_refused:
            bob.call("keys.reload")
        assert reload_refused.value.code == P.FORBIDDEN
        with pytest.raises(RemoteError) as record_refused:  # the lab PC's disk is an operator's to fill
            bob.record_start()
        assert record_refused.value.code == P.FORBIDDEN and record_refused.value.data["role"] == "observer"
        with pytest.raises(RemoteError) as snapshot_refused:
            bob.record_snapshot()
        assert snapshot_refused.value.code == P.FORBIDDEN
        for name in ("../etc/passwd", "x" * 81, ".hidden"):  # but the arguments come first (the order of checks)
            with pytest.raises(RemoteError) as malformed:
                bob.record_start(name)
            assert (malformed.value.code, malformed.value.data) == (P.BAD_ARGS, {"argument": "name"}), name
        assert bob.record_list()["active"] == []  # but he may see what is recorded
        alice.acquire_lease()
        alice.keep_lease()
        try:
            alice.enable()
            sub = alice.subscribe((b"event",))
            sub.wait_until_heard()
            bob.estop("panel")
            status = alice.status()
            assert status["state"] == "estop" and status["cause"] == "e-stop from bob (panel)"
            alice.reset()
            events = [m for _, m in iter(lambda: sub.receive(1.0), None)]
            sub.close()
            resets = [m for m in events if m["kind"] == "state" and (m["from"], m["to"]) == ("estop", "idle")]
            assert len(resets) == 1 and resets[0]["who"] == "alice", events  # the reset, signed
        finally:
            alice.release_lease()


def test_the_lease_is_bound_to_the_key_that_took_it(lab):
    _, eps, files = lab
    with client(eps, files["alice"]) as alice, client(eps, files["carol"], files["server"]) as carol:
        alice.acquire_lease()
        try:
            assert carol.status()["lease_holder"] == "alice"
            carol.lease = alice.lease  # a token seen over someone's shoulder
            with pytest.raises(RemoteError) as stolen:
                carol.enable()
            assert stolen.value.code == P.FORBIDDEN and stolen.value.data["holder"] == "alice"
            carol.lease = None
            with pytest.raises(RemoteError) as held:
                carol.acquire_lease()
            assert held.value.code == P.LEASE_HELD and held.value.data == {"reason": "held", "holder": "alice"}
        finally:
            alice.release_lease()


def test_a_revoked_key_is_refused_on_its_open_connection_and_its_telemetry_stops(lab, tmp_path):
    _, eps, files = lab
    handed = tmp_path / "dave"
    handed.mkdir()
    dave_file = keys.make_client(files["dir"], "dave", keys.OPERATOR, str(handed))
    with client(eps, files["alice"]) as alice:
        assert "dave" in alice.call("keys.reload")["allowed"]
        with client(eps, dave_file) as dave:
            assert dave.status()["client"]["name"] == "dave"
            sub = dave.subscribe((b"state",))
            alice_sub = alice.subscribe((b"state",))
            assert sub.receive(5.0) is not None
            keys.revoke(files["dir"], "dave")
            changes = alice.call("keys.reload")
            assert changes["removed"] == ["dave"] and "dave" not in changes["allowed"]
            with pytest.raises(RemoteError) as revoked:
                dave.status()  # the same connection as before
            assert revoked.value.code == P.FORBIDDEN and revoked.value.data == {"reason": "revoked", "key": "dave"}
            while sub.receive(0.5) is not None:  # what was queued before the publisher was bound again
                pass
            assert sub.receive(1.0) is None  # nothing since
            assert alice_sub.receive(5.0) is not None  # an allowed subscriber is admitted again
            sub.close()
            alice_sub.close()
        with client(eps, dave_file, timeout=1.5) as again, pytest.raises(KeyRefused):
            again.status()


def test_sighup_reloads_the_allow_list(lab, tmp_path):
    proc, eps, files = lab
    erin_file = keys.make_client(files["dir"], "erin", keys.OBSERVER, str(tmp_path))
    proc.send_signal(signal.SIGHUP)  # as systemctl reload does
    deadline = time.monotonic() + 60  # the reload is waited for; a busy machine takes its time
    while True:
        with client(eps, erin_file, timeout=2.0) as erin:
            try:
                assert erin.status()["client"] == {"name": "erin", "role": "observer"}
                break
            except KeyRefused:  # the reload had not happened when the handshake came
                assert time.monotonic() < deadline
        time.sleep(0.2)
    keys.revoke(files["dir"], "erin")
    proc.send_signal(signal.SIGHUP)


def test_pneumactl_takes_a_key_file_and_reports_a_refusal(lab):
    _, eps, files = lab
    endpoints = sum(([f"--{k}", v] for k, v in eps.items()), [])
    ctl = [sys.executable, "-m", "daemon.client.ctl", *endpoints]
    done = subprocess.run([*ctl, "--key", files["alice"], "status"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and '"name": "alice"' in done.stdout, done.stderr
    refused = subprocess.run([*ctl, "--timeout", "1", "status"], capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and "wants a key" in refused.stderr
    no_server = subprocess.run([*ctl, "--key", files["carol"], "status"], capture_output=True, text=True, timeout=60)
    assert no_server.returncode == 2 and "--server-key" in no_server.stderr


def test_binding_past_loopback_without_keys_is_refused_unless_insecure(tmp_path):
    port, control, telemetry = free_tcp_ports(3)
    exposed = [f"tcp://0.0.0.0:{port}", f"tcp://127.0.0.1:{control}", f"tcp://127.0.0.1:{telemetry}"]
    args = [sys.executable, "-m", "daemon.main", "run", "--no-rt", "--command", exposed[0], "--control", exposed[1],
            "--telemetry", exposed[2]]
    refused = subprocess.run(args, capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and "--insecure" in refused.stderr and "--keys" in refused.stderr
    proc = subprocess.Popen([*args, "--insecure", "--log-level", "WARNING"], stderr=subprocess.PIPE, text=True)
    try:
        with Client(f"tcp://127.0.0.1:{port}", exposed[1], exposed[2], timeout=10.0) as c:
            c.call("ping", timeout=60.0)
            security = c.status()["security"]
            assert security["mode"] == "insecure" and "anyone who can reach" in security["warning"]
            assert c.describe()["security"] == security
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=10)
    assert "no authentication" in err  # said in the log at start


def test_key_files_are_private_and_bad_ones_are_named(tmp_path):
    public, secret = keys.init_server(str(tmp_path / "d"))
    assert os.stat(secret).st_mode & 0o777 == 0o600 and os.stat(public).st_mode & 0o077 == 0o044
    with pytest.raises(keys.KeyFileError, match="exists already"):
        keys.init_server(str(tmp_path / "d"))
    os.chmod(secret, 0o644)
    with pytest.raises(keys.KeyFileError, match="readable by others"):
        keys.server_pair(str(tmp_path / "d"))
    os.chmod(secret, 0o600)
    keys.make_client(str(tmp_path / "d"), "ann", keys.OPERATOR, str(tmp_path))
    with pytest.raises(keys.KeyFileError, match="allowed already"):
        keys.allow(str(tmp_path / "d"), "ann", keys.OBSERVER, keys.server_pair(str(tmp_path / "d"))[0])
    with pytest.raises(keys.KeyFileError, match="key name"):
        keys.make_client(str(tmp_path / "d"), "../etc/x", keys.OPERATOR, str(tmp_path))
    broken = tmp_path / "d" / keys.CLIENTS / "broken.key"
    broken.write_text("metadata\ncurve\n    public-key = \"short\"\n")
    allowed = keys.AllowList(str(tmp_path / "d"))
    assert [c.name for c in allowed.clients.values()] == ["ann"]
    assert "broken.key" in allowed.problems[0] and "40 Z85 characters" in allowed.problems[0]
    with pytest.raises(keys.KeyFileError, match="no secret key"):
        keys.read_key_pair(public, need_secret=True)


def test_a_secret_key_written_inside_a_git_work_tree_is_said_never_to_be_committed(tmp_path):
    """README.md's keys lines run in a checkout (a git work tree): each secret key file they
    write is named on stderr with the warning, 0600 as ever; the public ones get none, nor do
    the same lines outside a work tree. So does ``pneumactl keys new``."""
    checkout, elsewhere = tmp_path / "checkout", tmp_path / "elsewhere"
    for where in (checkout, elsewhere):
        where.mkdir()
    subprocess.run(["git", "init", "-q", str(checkout)], check=True)

    def run(where, *args, module="daemon.main"):
        done = subprocess.run([sys.executable, "-m", module, *args], cwd=where, capture_output=True, text=True,
                              timeout=60)
        assert done.returncode == 0, done.stderr
        return [line for line in done.stderr.splitlines() if "must never be committed" in line]

    for where, warned in ((checkout, True), (elsewhere, False)):
        said = run(where, "keys", "--keys", "lab-keys", "init") + run(where, "keys", "--keys", "lab-keys", "client",
                                                                      "alice")
        said += run(where, "keys", "new", "carol", "--dir", "mine", module="daemon.client.ctl")
        secrets = ("lab-keys/server.key_secret", "alice.key_secret", "mine/carol.key_secret")
        if warned:
            assert len(said) == 3 and all(name in line and str(checkout) in line for name, line in zip(secrets, said)), said
        else:
            assert said == []
        for name in secrets:
            assert os.stat(where / name).st_mode & 0o777 == 0o600


def test_a_request_never_makes_the_daemon_open_a_file(lab):
    """Designs travel as content; a path where a design belongs is refused, never read."""
    _, eps, files = lab
    with client(eps, files["alice"], timeout=10.0) as alice:
        alice.acquire_lease()
        try:
            with pytest.raises(RemoteError) as refused:
                alice.call("controller.switch", {"name": "lti", "options": {"design": "/etc/passwd"}})
            assert refused.value.code == P.BAD_ARGS and "must be a map" in refused.value.message
        finally:
            alice.release_lease()


def test_a_routed_request_carries_who_sent_it_and_its_envelope_to_the_loop():
    """The messenger decodes a request once and hands the loop who sent it, its envelope and
    where its arguments lie; the loop's decoding of the arguments reads the same bytes."""
    body = P.encode_request("r-7", "set", {"angles_deg": [120.0, -90.0]}, "L1")
    for identity in (keys.ANONYMOUS, keys.Identity("alice", "operator"), keys.Identity("b" * 64, "observer")):
        for request in (P.decode_request(body), P.decode_request(P.encode_request(3, "ping", None, None))):
            who, routed_request = routed.unpack(routed.pack(identity, request))
            assert who == identity
            assert {k: routed_request[k] for k in ("id", "cmd", "lease")} == {k: request[k] for k in ("id", "cmd", "lease")}
            assert P.decode_args(routed_request) == P.decode_args(request)
    assert P.decode_args(routed.unpack(routed.pack(keys.ANONYMOUS, P.decode_request(body)))[1]) == {
        "angles_deg": [120.0, -90.0]}
