"""The protocol fuzzer (bench/fuzz.py), a short run in the suite: hostile and malformed frames
at a real daemon get a documented error or a result, never silence, an ``internal`` reply or
a change of the arm's state by a frame that was rejected, and the daemon lives on."""
import pytest

from bench.fuzz import fuzz
from daemon.client.client import Client
from tests.daemons import real_daemon, wait_for_own_daemon


@pytest.fixture
def daemon(tmp_path):
    proc, eps = real_daemon(tmp_path)
    try:
        wait_for_own_daemon(Client(**eps), proc)
        yield proc, eps
    finally:
        proc.terminate()
        proc.wait(120)  # its exit is waited for: a daemon beside CPU hogs has taken over 10 s to finish


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.slow  # long: kept out of the fast subset
def test_fuzzed_frames_get_documented_replies_and_change_nothing_they_are_refused(daemon, seed):
    proc, eps = daemon
    tally = fuzz(eps, 1000, seed)
    assert proc.poll() is None, "the daemon died"
    assert tally.replies == tally.frames == 1000 and tally.no_reply == 0, tally.examples
    assert tally.internal == 0 and tally.undocumented == 0, tally.examples
    assert tally.changed_by_rejected == 0, tally.examples
    assert tally.accepted and len(tally.codes) >= 5  # it reached deep: valid commands and many refusals
