"""A short soak (bench/soak.py) in the suite: a real daemon at full telemetry with healthy, slow
and stalled subscribers, paths, controller switches and gain changes, and its messenger
killed twice: the healthy subscribers lose nothing but what each kill had in flight, the
messenger comes back each time, and nothing trips. The hour-long run is the bench's."""
import pytest

from bench.soak import soak
from tests.daemons import real_daemon
from daemon.testing.daemons import STOP_WAIT_S

pytestmark = pytest.mark.slow


@pytest.mark.slow(seconds=16)
def test_a_short_soak_loses_nothing_outside_the_messenger_kills_and_trips_nothing(tmp_path):
    daemon, eps = real_daemon(tmp_path)
    try:
        # on past 12 s until two kills: a busy machine restarts a messenger slowly, and the next
        # kill waits for that restart
        report = soak(daemon.pid, eps, seconds=12.0, kill_every=4.0, min_kills=2)
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    assert report["trips"] == 0, report["trip_causes"]
    assert report["kills"] >= 2 and report["messenger_restarts"] == report["kills"]
    assert report["healthy_gaps_outside_kills"] == [0, 0, 0], report
    assert min(report["healthy_messages"]) > 500 and report["slow_messages"] > 50
    assert report["paths"] >= 1 and report["switches"] >= 1
