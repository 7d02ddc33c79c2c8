"""Every command of docs/protocol.md, accepted and refused, with its largest allowed arguments
(bench/command_cases.py), sent to a real daemon whose own process cannot plan
(tests/forbid_planning.py): each gets its documented reply, none reaches planning code in the
loop's process (that would answer ``internal``), and none trips the loop. How long the loop
took meanwhile is bench/command_stall.py's to measure, not a test's."""
import subprocess
import sys

import pytest

from bench.command_cases import CASES, prepare, send
from daemon.client import Client, RemoteError

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("every-command")
    eps = {name: f"ipc://{tmp}/{name}" for name in ("command", "control", "telemetry")}
    proc = subprocess.Popen([sys.executable, "-m", "tests.forbid_planning", "run", "--no-rt", "--log-level", "WARNING",
                             *sum(([f"--{k}", v] for k, v in eps.items()), [])])
    client = Client(**eps, timeout=5.0)
    try:
        client.call("ping", timeout=60.0)
        client.acquire_lease(ttl_s=60.0)
        client.keep_lease()
        yield client
    finally:
        client.close()
        proc.terminate()
        proc.wait(10)


@pytest.mark.parametrize("case", CASES, ids=[c.label for c in CASES])
def test_every_command_gets_its_documented_reply_and_never_stalls_the_loop(daemon, case):
    prepare(daemon, case)
    trips = daemon.status()["trips"]
    reply = send(daemon, case)
    code = reply.code if isinstance(reply, RemoteError) else None
    assert code == case.expect, f"{case.label}: {reply}"
    if isinstance(reply, RemoteError):
        assert reply.message and reply.code != "internal"
    status = daemon.status()
    assert status["trips"] == trips, status["cause"]
