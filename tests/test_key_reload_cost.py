"""What a key reload costs a subscriber (docs/protocol.md, Keys): nothing when it removed no
key; when it removed one, the telemetry socket is bound again once the reload's events are
published (its own ``keys`` event, the loop's if a lease ended), and every allowed subscriber
loses what is published after that until it is admitted again, then receives again. A real
daemon with keys, on private endpoints."""
from __future__ import annotations

import time

import pytest

from daemon.client.client import Client
from daemon.testing.daemons import STOP_WAIT_S
from daemon.wire import keys
from tests.daemons import real_daemon

pytestmark = pytest.mark.slow


def received(sub, seconds: float) -> list[tuple[str, dict]]:
    end, out = time.monotonic() + seconds, []
    while time.monotonic() < end:
        message = sub.receive(0.2)
        if message is not None:
            out.append(message)
    return out


def state_gaps(messages) -> int:
    """Messages missing between those received (each topic counts its own ``seq``)."""
    seqs = [m["seq"] for topic, m in messages if topic == "state"]
    return sum(b - a - 1 for a, b in zip(seqs, seqs[1:]))


def test_a_reload_that_removes_a_key_reaches_subscribers_with_its_event_and_one_that_removes_none_costs_nothing(
        tmp_path):
    server_dir, handed = tmp_path / "server", tmp_path / "handed"
    handed.mkdir()
    keys.init_server(str(server_dir))
    alice = keys.make_client(str(server_dir), "alice", keys.OPERATOR, str(handed))
    keys.make_client(str(server_dir), "dave", keys.OPERATOR, str(handed))
    proc, eps = real_daemon(tmp_path, "--keys", str(server_dir))
    try:
        with Client(**eps, timeout=10.0, key_file=alice) as client:
            client.call("ping", timeout=60.0)
            sub = client.subscribe((b"state", b"event"))
            assert received(sub, 1.0), "no telemetry before the reloads"
            assert client.call("keys.reload")["removed"] == []
            calm = received(sub, 1.5)
            assert state_gaps(calm) == 0 and any(m.get("kind") == "keys" for t, m in calm if t == "event")
            keys.revoke(str(server_dir), "dave")
            assert client.call("keys.reload")["removed"] == ["dave"]
            after = received(sub, 3.0)
            reloads = [m for t, m in after if t == "event" and m["kind"] == "keys"]
            assert [(m["removed"], m["who"]) for m in reloads] == [(["dave"], "alice")], \
                "the removing reload's own event did not reach a subscriber: published after the re-bind"
            assert after and after[-1][0] in ("state", "event")  # admitted again: it receives
            sub.close()
    finally:
        proc.terminate()
        proc.wait(STOP_WAIT_S)
