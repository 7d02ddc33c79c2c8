"""Revoking a key on a running daemon as the documents say (`pneumad keys revoke NAME`, then
`pneumactl keys reload`; systemctl reload's SIGHUP is tests/test_security.py's): the key is
refused from then on, and a lease it held ends at once. The arm stops what it was doing for
that key and follows the unleased policy, and another key may take the lease straight away."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import msgpack
import pytest
import zmq

from daemon.client.client import Client, RemoteError
from daemon.testing.daemons import STOP_WAIT_S
from daemon.wire import keys
from daemon.wire import protocol as P
from tests.daemons import endpoint_env, real_daemon
from tests.schemas import schema

pytestmark = pytest.mark.slow(seconds=60)
TTL_S = 60.0  # the revoked key's lease: far longer than any step here waits


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """A daemon with keys, its log in a file: bea (an operator, who reloads) and vic (an
    observer); each test allows its own keys."""
    root = tmp_path_factory.mktemp("revocation")
    server_dir, handed = root / "server", root / "handed"
    handed.mkdir()
    keys.init_server(str(server_dir))
    files = {"dir": str(server_dir), "log": str(root / "daemon.log"),
             "bea": keys.make_client(str(server_dir), "bea", keys.OPERATOR, str(handed)),
             "vic": keys.make_client(str(server_dir), "vic", keys.OBSERVER, str(handed))}
    with open(files["log"], "w") as log:
        proc, eps = real_daemon(root, "--keys", str(server_dir), stderr=log)
    try:
        with Client(**eps, timeout=10.0, key_file=files["bea"]) as c:
            c.call("ping", timeout=60.0)
        yield proc, eps, files
    finally:
        proc.terminate()
        proc.wait(STOP_WAIT_S)


def client(eps, key_file, timeout=10.0) -> Client:
    return Client(**eps, timeout=timeout, key_file=key_file)


def pneumactl(eps, key_file, *words) -> subprocess.CompletedProcess:
    """``pneumactl --key FILE WORDS`` as a user types it, the endpoints from the environment."""
    return subprocess.run([sys.executable, "-m", "daemon.client.ctl", "--timeout", "10", "--key", key_file, *words],
                          env=endpoint_env(eps), capture_output=True, text=True, timeout=120)


def reload_as_documented(eps, files) -> dict:
    done = pneumactl(eps, files["bea"], "keys", "reload")
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def allow(files, name, tmp_path) -> str:
    return keys.make_client(files["dir"], name, keys.OPERATOR, str(tmp_path))


def test_pneumactl_keys_reload_revokes_a_key_as_the_documents_say(lab, tmp_path):
    _, eps, files = lab
    erin = allow(files, "erin", tmp_path)
    assert "erin" in reload_as_documented(eps, files)["added"]
    with client(eps, erin) as c:
        assert c.status()["client"]["name"] == "erin"
        revoked = subprocess.run([sys.executable, "-m", "daemon.main", "keys", "--keys", files["dir"], "revoke", "erin"],
                                 capture_output=True, text=True, timeout=60)
        assert revoked.returncode == 0 and "pneumactl keys reload" in revoked.stdout, revoked.stderr
        assert reload_as_documented(eps, files)["removed"] == ["erin"]
        with pytest.raises(RemoteError) as refused:
            c.status()  # the connection made before
        assert refused.value.code == P.FORBIDDEN and refused.value.data == {"reason": "revoked", "key": "erin"}
    observer = pneumactl(eps, files["vic"], "keys", "reload")  # an operator's command (the catalog's role)
    assert observer.returncode == 1 and "forbidden" in observer.stderr and '"role": "observer"' in observer.stderr


def test_the_keys_event_of_a_reload_names_who_reloaded(lab, tmp_path):
    _, eps, files = lab
    allow(files, "fay", tmp_path)
    with client(eps, files["vic"]) as vic:  # an observer watching
        sub = vic.subscribe((b"event", b"state"))
        try:
            assert sub.receive(30.0) is not None  # admitted: it hears the events to come
            assert reload_as_documented(eps, files)["added"] == ["fay"]
            reloaded = events_until(sub, "keys")[-1]
            assert reloaded["who"] == "bea" and reloaded["added"] == ["fay"] and "by bea" in reloaded["cause"]
            schema("telemetry", "event").validate(reloaded)
        finally:
            sub.close()


def events_until(sub, kind: str, limit_s: float = 30.0) -> list[dict]:
    """Events up to and including the first of ``kind`` (failing after ``limit_s``)."""
    seen, deadline = [], time.monotonic() + limit_s
    while time.monotonic() < deadline:
        got = sub.receive(1.0)
        if got is not None and got[0] == "event":
            seen.append(got[1])
            if got[1]["kind"] == kind:
                return seen
    raise AssertionError(f"no {kind} event within {limit_s} s: {seen}")


def logged(path: str, words: tuple[str, ...], limit_s: float = 30.0) -> str:
    """The first line of the daemon's log holding every one of ``words``."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        with open(path) as f:
            for line in f:
                if all(w in line for w in words):
                    return line
        time.sleep(0.2)
    raise AssertionError(f"no log line with {words} within {limit_s} s")


def test_a_revoked_keys_lease_ends_at_once_and_its_path_stops(lab, tmp_path):
    """ann takes the lease, enables and starts a long path; her key is removed and reloaded:
    her lease ends at once (status, an event naming her, the log), the path stops and the arm
    holds under the unleased policy, and bea's lease.acquire succeeds at once, where it got
    ``lease_held`` until ann's time to live ran out."""
    _, eps, files = lab
    ann_file = allow(files, "ann", tmp_path)
    reload_as_documented(eps, files)
    with client(eps, files["bea"]) as bea, client(eps, ann_file) as ann:
        sub = bea.subscribe((b"event", b"state"))
        assert sub.receive(30.0) is not None  # admitted: it hears the events to come
        ann.acquire_lease(TTL_S)
        ann.enable()
        ann.path("circle", duration_s=600.0)
        status = bea.status()
        assert status["lease_holder"] == "ann" and status["reference"] == "circle"
        assert status["reference_remaining_s"] > 60.0
        keys.revoke(files["dir"], "ann")
        reloaded_at = time.monotonic()
        assert reload_as_documented(eps, files)["removed"] == ["ann"]
        status = bea.status()  # the loop had the revocation before this request
        assert status["lease_held"] is False and status["lease_holder"] is None
        assert status["state"] == "enabled" and status["reference"] == "hold"
        assert status["reference_remaining_s"] == 0.0
        assert 0.0 < status["unleased_disable_in_s"] <= 60.0  # the rig file's policy: disabled after its grace
        bea.acquire_lease()  # at once: not ann's until her 60 s lapse
        assert time.monotonic() - reloaded_at < TTL_S / 2
        for control in (False, True):  # the messenger's word to the loop: no client may send it
            with pytest.raises(RemoteError) as unknown:
                bea.call("lease.revoke", {"key": "bea"}, control=control)
            assert unknown.value.code == P.UNKNOWN_COMMAND
            assert "lease.revoke" not in unknown.value.message.split("serves")[1]
        assert bea.status()["lease_holder"] == "bea"
        try:
            seen = events_until(sub, "lease_revoked")
            revoked = seen[-1]
            assert revoked["key"] == "ann" and revoked["who"] == "bea" and "'ann'" in revoked["cause"]
            assert "unleased" in revoked["cause"]
            reloads = [e for e in seen if e["kind"] == "keys" and e["removed"] == ["ann"]]
            assert len(reloads) == 1 and reloads[0]["who"] == "bea"
            ends = [e for e in seen if e["kind"] == "reference" and e["action"] == "end" and e["name"] == "circle"]
            assert len(ends) == 1 and ends[0]["cut"] == "replaced by hold" and ends[0]["who"] == "bea"
            for event in seen:
                schema("telemetry", "event").validate(event)
            assert "'ann'" in logged(files["log"], ("lease", "revoked", "'ann'"))
        finally:
            sub.close()
            bea.disable()
            bea.release_lease()


def test_a_lease_acquire_the_revoked_key_sent_before_the_reload_is_ended_after_it(lab, tmp_path):
    """A request of the key's already queued for the loop when the reload comes runs after the
    revocation that overtook it: a lease it takes so is ended too. The loop is stopped
    (SIGSTOP) so that ann's lease.acquire waits in its queue while the key is revoked."""
    proc, eps, files = lab
    ann_file = allow(files, "cal", tmp_path)
    reload_as_documented(eps, files)
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    keys.secure_client(sock, ann_file)
    sock.connect(eps["command"])
    with client(eps, files["bea"]) as bea:
        assert bea.status()["lease_held"] is False
        os.kill(proc.pid, signal.SIGSTOP)  # the loop's process; the messenger's runs on
        try:
            sock.send(P.encode_request(1, "lease.acquire", {"ttl_s": TTL_S}, None))
            sock.send(P.encode_request(2, "keys.reload", None, None))  # the messenger's own: answered now
            assert sock.poll(30_000), "the messenger did not answer while the loop was stopped"
            assert msgpack.unpackb(sock.recv_multipart()[-1])["id"] == 2  # so the acquire is queued
            keys.revoke(files["dir"], "cal")
            assert bea.call("keys.reload")["removed"] == ["cal"]
        finally:
            os.kill(proc.pid, signal.SIGCONT)
        assert sock.poll(30_000)
        acquired = msgpack.unpackb(sock.recv_multipart()[-1])
        assert acquired["id"] == 1 and acquired["ok"]  # granted: the revocation had overtaken it ...
        status = bea.status()
        assert status["lease_held"] is False, status  # ... and the one behind it ended it
    sock.close()


def test_a_key_made_an_observer_while_it_holds_the_lease_loses_it_at_once(lab, tmp_path):
    """dan takes the lease, enables and starts a long path; his key stays on the allow-list
    but as an observer (revoked and allowed again with the role, then one reload): his lease ends at
    once, as a removed key's, where it would otherwise lapse at its time to live (his renewals
    forbidden to an observer) and trip the enabled arm; the path stops, the arm holds, bea
    takes the lease at once, and dan, still connected, is an observer."""
    _, eps, files = lab
    dan_file = allow(files, "dan", tmp_path)
    reload_as_documented(eps, files)
    public, _ = keys.read_key_pair(dan_file, need_secret=False)
    with client(eps, files["bea"]) as bea, client(eps, dan_file) as dan:
        sub = bea.subscribe((b"event", b"state"))
        assert sub.receive(30.0) is not None
        dan.acquire_lease(TTL_S)
        dan.enable()
        dan.path("circle", duration_s=600.0)
        keys.revoke(files["dir"], "dan")
        keys.allow(files["dir"], "dan", keys.OBSERVER, public)
        changes = reload_as_documented(eps, files)
        assert changes["changed"] == ["dan"] and changes["removed"] == [] and "dan" in changes["allowed"]
        status = bea.status()
        assert status["lease_held"] is False and status["state"] == "enabled" and status["reference"] == "hold"
        bea.acquire_lease()
        assert dan.status()["client"] == {"name": "dan", "role": "observer"}
        with pytest.raises(RemoteError) as refused:
            dan.acquire_lease()
        assert refused.value.code == P.FORBIDDEN
        try:
            seen = events_until(sub, "lease_revoked")
            ended = seen[-1]
            assert ended["key"] == "dan" and "another key or role" in ended["cause"] and "unleased" in ended["cause"]
            assert [e["changed"] for e in seen if e["kind"] == "keys"][-1] == ["dan"]
            for event in seen:
                schema("telemetry", "event").validate(event)
            assert "'dan'" in logged(files["log"], ("lease", "'dan'", "another key or role"))
        finally:
            sub.close()
            bea.disable()
            bea.release_lease()
