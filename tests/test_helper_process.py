"""The helper-process handle (hal.process) that every process beside the loop is started by:
the ready handshake and its failures, restart, join, die-with-parent, placement, shared memory."""
from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import time

import pytest

from hal.process import Helper, HelperFailed, SharedMemory
from tests.daemons import running
from daemon.testing.daemons import STOP_WAIT_S

HERE = "tests.test_helper_process"


# -- the children (run in the helper process) ---------------------------------------------------
def _serve_until_told(child, shared):
    """Ready with its pid and nice, count up in shared memory until the stop flag or the parent's end."""
    child.ready({"pid": os.getpid(), "nice": os.getpriority(os.PRIO_PROCESS, 0)})
    while not shared.stop.value and child.parent_alive():
        shared.beats.value += 1
        shared.trace[:] = [shared.beats.value] * 3
        time.sleep(0.01)
    return 0


def _serve_after_standby(child, shared):
    """Import-time work done, then wait as a spare would; once in service, count the
    standbys passed and serve as _serve_until_told."""
    child.standby()
    shared.served.value += 1
    return _serve_until_told(child, shared)


def _silent(child):
    time.sleep(600)


def _refuses(child, words):
    raise HelperFailed(words)


def _exits(child, code):
    return code


def _stubborn(child):
    child.ready()
    while True:  # ignores SIGTERM (the handle's default), never ends by itself
        time.sleep(0.05)


def _shared():
    return SharedMemory({"stop": ctypes.c_bool, "beats": ctypes.c_uint64, "trace": ctypes.c_double * 3,
                         "served": ctypes.c_uint64})


def _wait_gone(pid: int, limit_s: float = 10.0) -> bool:
    end = time.monotonic() + limit_s
    while running(pid) and time.monotonic() < end:
        time.sleep(0.02)
    return not running(pid)


def _first_code(helper: Helper, limit_s: float = 10.0) -> int | None:
    """Check as the daemon does (never waiting; it checks once a second) until the check sees
    the child dead: a killed child can be reaped only once all its threads have ended, a
    moment after /proc shows it a zombie. The old child's exit code, None if never seen."""
    end = time.monotonic() + limit_s
    while (code := helper.restart_if_dead()) is None and time.monotonic() < end:
        time.sleep(0.02)
    return code


# -- the tests ----------------------------------------------------------------------------------
def test_a_ready_child_shares_memory_and_stops_when_told():
    shared = _shared()
    helper = Helper(f"{HERE}:_serve_until_told", (shared,), pass_fds=(shared.fd,), nice=7)
    said = helper.start()
    assert said["pid"] == helper.pid and said["nice"] >= 7  # placed before it ran
    end = time.monotonic() + 10.0
    while shared.beats.value < 3 and time.monotonic() < end:
        time.sleep(0.01)
    assert shared.beats.value >= 3 and shared.trace[0] >= 3  # the child writes where the parent reads
    shared.stop.value = True
    assert helper.join(10.0) == 0 and not helper.alive


def test_a_child_that_dies_is_seen_and_started_again():
    shared = _shared()
    helper = Helper(f"{HERE}:_serve_until_told", (shared,), pass_fds=(shared.fd,))
    first = helper.start()["pid"]
    assert helper.restart_if_dead() is None  # alive: nothing done
    os.kill(first, signal.SIGKILL)
    assert _first_code(helper) == -signal.SIGKILL
    assert helper.restarts == 1
    second = helper.wait_ready()["pid"]
    assert second != first and helper.alive
    shared.stop.value = True
    assert helper.join(10.0) == 0


def test_a_spare_waits_past_its_imports_and_takes_a_dead_childs_place_at_once():
    """``spare=True``: a second child waits at Child.standby (nothing of its predecessor's
    taken) until the first dies; then it goes on, with no interpreter to start, and the next
    spare follows once it is ready. Stopping the helper ends the spare too."""
    shared = _shared()
    helper = Helper(f"{HERE}:_serve_after_standby", (shared,), pass_fds=(shared.fd,), spare=True)
    first = helper.start()["pid"]
    assert helper.restart_if_dead() is None  # alive and ready: its spare is started
    spare = helper._spare.pid
    assert spare != first and running(spare)
    time.sleep(0.5)
    assert shared.served.value == 1  # the spare waits: it has not gone past its standby
    os.kill(first, signal.SIGKILL)
    assert _first_code(helper) == -signal.SIGKILL
    assert helper.pid == spare and helper.wait_ready(30.0)["pid"] == spare and shared.served.value == 2
    assert helper.health() == {"running": True, "pid": spare, "restarts": 1, "last_exit_code": -signal.SIGKILL}
    assert helper.restart_if_dead() is None and helper._spare is not None  # the next spare
    following = helper._spare.pid
    shared.stop.value = True
    assert helper.join(10.0) == 0
    assert _wait_gone(following) and shared.served.value == 2  # dismissed, never served


def test_a_child_that_never_says_ready_is_a_clear_error_within_its_limit():
    helper = Helper(f"{HERE}:_silent")
    started = time.monotonic()
    with pytest.raises(HelperFailed, match=r"not ready within 1\.5 s of starting"):
        helper.start(limit_s=1.5)
    assert time.monotonic() - started < 10.0
    assert not helper.alive  # and it was stopped, not left behind


def test_a_refusal_is_told_in_the_childs_words_and_an_early_exit_with_its_code():
    with pytest.raises(HelperFailed, match="^cannot bind the command endpoint tcp://x$"):
        Helper(f"{HERE}:_refuses", ("cannot bind the command endpoint tcp://x",)).start()
    with pytest.raises(HelperFailed, match=r"exited \(code 3\) before it was ready"):
        Helper(f"{HERE}:_exits", (3,)).start()
    with pytest.raises(HelperFailed, match="cannot load"):
        Helper(f"{HERE}:no_such_function").start()


def test_join_stops_a_child_that_will_not_end_by_itself():
    helper = Helper(f"{HERE}:_stubborn")
    helper.start()
    pid = helper.pid
    started = time.monotonic()
    assert helper.join(0.3, terminate_first=True) == -signal.SIGKILL  # SIGTERM ignored, so killed
    assert time.monotonic() - started < 10.0 and not running(pid)


PARENT = """
import ctypes, sys, time
sys.path[:0] = sys.argv[1:]
from hal.process import Helper, SharedMemory
shared = SharedMemory({"stop": ctypes.c_bool, "beats": ctypes.c_uint64})
helper = Helper("tests.test_helper_process:_serve_until_told", (shared,), pass_fds=(shared.fd,))
print(helper.start()["pid"], flush=True)
time.sleep(600)
"""


def test_the_child_dies_with_its_parent_when_the_parent_is_killed():
    parent = subprocess.Popen([sys.executable, "-c", PARENT, *sys.path], stdout=subprocess.PIPE, text=True)
    try:
        child = int(parent.stdout.readline())
        assert running(child)
        parent.send_signal(signal.SIGKILL)
        parent.wait(STOP_WAIT_S)
        assert _wait_gone(child)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        parent.stdout.close()


def test_arguments_that_will_not_pickle_fail_before_any_child_is_started():
    helper = Helper(f"{HERE}:_exits", (lambda: 0,))
    with pytest.raises(Exception, match="pickle"):
        helper.start()
    assert helper.pid is None
