"""The journal: every trip, e-stop, reset, enable and disable, lease change and controller switch
of a real daemon is one line of its log (its stderr: under systemd, the journal), with its
cause, cycle and who; and a storm of events costs a bounded number of lines, the rest counted
(daemon/messenger/journal.py)."""
import logging
import re
import time

import pytest

from daemon.client.client import Client, RemoteError
from daemon.messenger.journal import BURST, RATE_PER_S, Journal
from daemon.testing.daemons import STOP_WAIT_S
from tests.daemons import real_daemon, wait_for_own_daemon
from tests.schemas import schema

pytestmark = pytest.mark.slow(seconds=40)


def next_event(sub, kind: str, limit_s: float = 60.0, **fields) -> dict:
    """The next event of ``kind`` with ``fields`` (others passed over)."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        got = sub.receive(1.0)
        if got is not None and got[0] == "event" and got[1]["kind"] == kind and \
                all(got[1].get(k) == v for k, v in fields.items()):
            return got[1]
    raise AssertionError(f"no {kind} event {fields} within {limit_s} s")


def journal_line(log, level: str, kind: str, event: dict, limit_s: float = 30.0) -> str:
    """The log line of ``event``: its level and kind, its cycle and its who (it is written as the
    messenger publishes the event, so it may come a moment after the event is received)."""
    where = f"[cycle {event['cycle']}" + (f", {event['who']}]" if event.get("who") else "]")
    deadline = time.monotonic() + limit_s
    while True:
        for line in log.read_text().splitlines():
            if line.startswith(f"pneumad messenger {level}: {kind}: ") and line.endswith(where):
                return line
        assert time.monotonic() < deadline, f"no {level} {kind} line ending {where!r} in:\n{log.read_text()}"
        time.sleep(0.1)


def test_a_real_daemons_trips_estops_resets_enables_and_lease_changes_are_lines_of_its_journal(tmp_path):
    """A lease that lapses trips the enabled arm (a real trip); then a reset, an enable, a switch,
    an e-stop, a reset and a disable: each is one line naming its cause, its cycle and who."""
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:
        daemon, eps = real_daemon(tmp_path, stderr=stderr)
    validate = schema("telemetry", "event")
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            sub = client.subscribe((b"event",))
            sub.wait_until_heard()
            client.acquire_lease(5.0)  # and never renewed
            client.enable()
            acquired = next_event(sub, "lease", action="acquire")
            enabled = next_event(sub, "state", to="enabled")
            lapsed = next_event(sub, "lease", action="expire")
            trip = next_event(sub, "trip")
            client.acquire_lease()
            client.keep_lease()
            client.reset()
            reset = next_event(sub, "state", to="idle")
            client.enable()
            enabled_again = next_event(sub, "state", to="enabled")
            client.switch_controller("smc")
            switched = next_event(sub, "controller")
            client.estop("the journal's test")
            estop = next_event(sub, "estop")
            client.reset()
            next_event(sub, "state", to="idle")
            client.enable()
            next_event(sub, "state", to="enabled")
            client.disable()
            disabled = next_event(sub, "state", to="idle")
            sub.close()
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    for event in (acquired, lapsed, enabled, reset, switched, estop, disabled, trip):
        validate.validate(event)
    assert (acquired["action"], lapsed["action"]) == ("acquire", "expire")
    assert "lease lost" in trip["cause"] and (reset["from"], reset["to"]) == ("fault", "idle")
    line = journal_line(log, "ERROR", "trip", trip)
    assert "lease lost: the controlling client (anonymous) stopped renewing it" in line
    assert "not renewed within 5 s" in journal_line(log, "WARNING", "lease", lapsed)
    assert "acquire anonymous (for 5 s at a time)" in journal_line(log, "INFO", "lease", acquired)
    assert "idle -> enabled (enabled)" in journal_line(log, "INFO", "state", enabled)
    assert "fault -> idle (reset)" in journal_line(log, "INFO", "state", reset)
    assert "idle -> enabled" in journal_line(log, "INFO", "state", enabled_again)
    assert "pid -> smc (switch)" in journal_line(log, "INFO", "controller", switched)
    assert "e-stop from the journal's test" in journal_line(log, "WARNING", "estop", estop)
    assert "enabled -> idle (disabled)" in journal_line(log, "INFO", "state", disabled)
    for event in (acquired, enabled, reset, switched, estop, disabled):
        assert event["who"] == "anonymous"  # each request's events name who sent it; the lapse is the loop's
    text = log.read_text()
    assert not re.search(r"state: \w+ -> (fault|estop)", text)  # said once, by the trip's and the e-stop's line


def test_a_storm_of_events_costs_a_bounded_number_of_lines_and_what_was_held_back_is_counted():
    """A thousand trips in a second: at most BURST lines at once and RATE_PER_S a second after
    that, then one line counting the rest by kind."""
    now = [100.0]
    lines: list[tuple[int, str]] = []

    class Collect(logging.Handler):
        def emit(self, record):
            lines.append((record.levelno, record.getMessage()))

    log = logging.getLogger("test-journal-storm")
    log.propagate = False
    log.addHandler(Collect())
    journal = Journal(log, clock=lambda: now[0])
    for i in range(1000):
        journal.write({"kind": "trip", "cause": f"storm {i}", "cycle": i})
        if i % 100 == 99:
            journal.write({"kind": "state", "from": "fault", "to": "idle", "cause": "reset", "cycle": i, "who": "x"})
        now[0] += 0.001
    written = [text for _, text in lines]
    assert BURST <= len(written) <= BURST + RATE_PER_S * 1.0 + 2
    assert written[0] == "trip: storm 0 [cycle 0]" and lines[0][0] == logging.ERROR
    now[0] += 1.0
    journal.flush()
    said = [text for _, text in lines if text.startswith("journal: ")]
    assert said and lines[-1][1] == said[-1]
    held = {kind: sum(int(n) for text in said for n in re.findall(rf"\b{kind} (\d+)", text)) for kind in ("trip", "state")}
    assert sum(int(re.match(r"journal: (\d+) more events not written", text).group(1)) for text in said) == \
        held["trip"] + held["state"]
    assert sum(text.startswith("trip: ") for text in written) + held["trip"] == 1000
    assert sum(text.startswith("state: ") for text in written) + held["state"] == 10
    journal.write({"kind": "trip", "cause": "after the storm", "cycle": 5000})
    assert lines[-1][1] == "trip: after the storm [cycle 5000]"  # the bucket filled again


def test_a_storm_of_estops_and_resets_from_a_client_is_bounded_in_the_daemons_log(tmp_path):
    """A real client sends 150 e-stops and resets as fast as it can: the daemon's log holds a
    bounded number of lines for them and says how many more it held back."""
    log = tmp_path / "daemon.log"
    with open(log, "w") as stderr:
        daemon, eps = real_daemon(tmp_path, stderr=stderr)
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
            client.acquire_lease()
            client.keep_lease()
            started = time.monotonic()
            for i in range(150):
                client.estop(f"storm {i}")
                try:
                    client.reset()
                except RemoteError:
                    pass
            took = time.monotonic() - started
            time.sleep(1.5)  # the messenger's next look says what it held back
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    text = log.read_text()
    lines = [line for line in text.splitlines() if re.match(r"pneumad messenger \w+: (estop|state): ", line)]
    assert len(lines) <= BURST + RATE_PER_S * (took + 2.0) + 2, (len(lines), took)
    held = sum(int(n) for n in re.findall(r"journal: (\d+) more events not written", text))
    assert held > 0 and len(lines) + held >= 300  # every e-stop and reset: a line, or counted
