"""Revoking a key on a running daemon as the documents say (`pneumad keys revoke NAME`, then
`pneumactl keys reload`; systemctl reload's SIGHUP is tests/test_security.py's): the key is
refused from then on."""
from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest

from daemon.client.client import Client, RemoteError
from daemon.wire import keys
from daemon.wire import protocol as P
from tests.daemons import endpoint_env, real_daemon
from tests.schemas import schema

pytestmark = pytest.mark.slow(seconds=60)


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
        proc.wait(10)


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
