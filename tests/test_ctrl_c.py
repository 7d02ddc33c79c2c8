"""Ctrl-C in pneumactl's long commands (issue: a 15-line traceback, and nothing said about what
kept running): each ends with one line and exit 130. Following a reference (``--wait``) stops
only the following, and says what runs on and the command that stops it; a recording made
here ends with its file whole; a client-side routine (``identify``) stops what it started."""
from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from bench.common import child_process
from daemon.client.client import Client
from daemon.recordings import mcap_log
from daemon.testing.daemons import STOP_WAIT_S
from tests.daemons import answering_daemon, endpoint_env, running
from tests.doc_runs import restore_sigint

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    with answering_daemon(tmp_path_factory.mktemp("ctrl-c")) as served:
        yield served


def interrupted(eps, tmp_path, *args: str, when) -> subprocess.CompletedProcess:
    """``pneumactl ARGS``, sent SIGINT (a terminal's Ctrl-C) once ``when(stderr_lines)`` holds
    (what it has printed so far: a piped progress line says it is following)."""
    proc = subprocess.Popen([sys.executable, "-m", "daemon.client.ctl", *args], cwd=tmp_path, env=endpoint_env(eps),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=restore_sigint)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stderr.readline, "")), daemon=True)
    reader.start()
    deadline = time.monotonic() + 120.0
    while not when(lines):
        assert proc.poll() is None, (proc.returncode, lines)
        assert time.monotonic() < deadline, ("the command never reached the point to interrupt", lines)
        time.sleep(0.1)
    proc.send_signal(signal.SIGINT)
    proc.wait(STOP_WAIT_S)
    reader.join(10)  # stderr read to its end by the reader alone
    out = proc.stdout.read()
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, "".join(lines))


def enabled_and_still(client: Client, eps) -> None:
    """The arm enabled (by pneumactl, as a user would) with nothing running: whatever an earlier
    test left running is aborted."""
    if client.status()["state"] != "enabled":
        assert subprocess.run([sys.executable, "-m", "daemon.client.ctl", "enable"],
                              env=endpoint_env(eps)).returncode == 0
    client.call("abort", control=True)


def one_line(done: subprocess.CompletedProcess) -> str:
    assert done.returncode == 130, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    return done.stderr.strip().splitlines()[-1]


def test_ctrl_c_while_following_a_path_says_what_runs_on_and_how_to_stop_it(daemon):
    client, eps, tmp_path = daemon
    assert subprocess.run([sys.executable, "-m", "daemon.client.ctl", "enable"], env=endpoint_env(eps)).returncode == 0
    done = interrupted(eps, tmp_path, "path", "translation", "--wait",
                       when=lambda printed: any("translation:" in line for line in printed))  # following it
    line = one_line(done)
    assert "runs on in the daemon" in line and "`pneumactl abort`" in line, line
    status = client.status()
    assert status["state"] == "enabled" and status["reference_remaining_s"] > 0.0  # following was all it stopped
    client.call("abort", control=True)


def test_ctrl_c_while_recording_here_ends_the_file_whole(daemon):
    _, eps, tmp_path = daemon
    path = tmp_path / "cut.mcap"
    done = interrupted(eps, tmp_path, "record", str(path), "--seconds", "60",
                       when=lambda _: path.exists() and path.stat().st_size > 50_000)
    assert "ended at Ctrl-C, whole up to there" in one_line(done)
    contents = mcap_log.read(path)
    assert not contents.truncated and len(contents.messages["state"]) > 10


def test_ctrl_c_during_identify_aborts_the_experiment_it_started(daemon):
    client, eps, tmp_path = daemon
    enabled_and_still(client, eps)

    def exciting(printed) -> bool:  # following its first experiment, an input-side excitation
        return any("-input:" in line for line in printed) and client.status()["reference_remaining_s"] > 1.0

    done = interrupted(eps, tmp_path, "identify", "bottom", "--quick", "--out", str(tmp_path / "identified"),
                       when=exciting)
    line = one_line(done)
    assert "identification stopped" in line and "was aborted" in line and "nothing was fitted" in line, line
    status = client.status()
    assert status["state"] == "enabled" and status["reference_remaining_s"] == 0.0 and not status["lease_held"]


def test_ctrl_c_during_payload_identify_aborts_its_move_and_stores_nothing(daemon):
    client, eps, tmp_path = daemon
    enabled_and_still(client, eps)
    reference = tmp_path / "unloaded.json"

    def moving(printed) -> bool:  # it said how long it will take, and its first move runs
        return any("payload identify:" in line for line in printed) and client.status()["reference_remaining_s"] > 0.5

    done = interrupted(eps, tmp_path, "payload", "identify", "--unloaded", "--reference", str(reference), when=moving)
    line = one_line(done)
    assert "payload routine stopped" in line and "was aborted" in line and "nothing was stored" in line, line
    assert not reference.exists()
    status = client.status()
    assert status["state"] == "enabled" and status["reference_remaining_s"] == 0.0 and not status["lease_held"]


# Ctrl-C the moment the routine's lease is taken: the script sends itself SIGINT right after the
# daemon granted it, before the routine renews it (where a terminal's Ctrl-C just after the
# routine said its plan lands on a loaded machine), then exits as pneumactl would.
def test_ctrl_c_while_identify_reads_its_recording_says_what_it_stopped(daemon):
    """``identify --from`` a recording that is still being read (a FIFO whose writer sends
    nothing: the read is where Ctrl-C finds it, deterministically): one line, exit 130."""
    _, eps, tmp_path = daemon
    fifo = tmp_path / "slow.mcap"
    os.mkfifo(fifo)
    writer = []

    def reading(_) -> bool:  # the reader has the FIFO open: it waits in its read
        try:
            writer.append(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        except OSError as exc:
            assert exc.errno == errno.ENXIO, exc
            return False
        return True
    try:
        done = interrupted(eps, tmp_path, "identify", "bottom", "--from", str(fifo), "--out", str(tmp_path / "read"),
                           when=reading)
    finally:
        for fd in writer:
            os.close(fd)
    assert one_line(done) == f"interrupted: reading {fifo} stopped; nothing was fitted or written"


@pytest.fixture(scope="module")
def experiments(daemon):
    """A recording of identify's experiments on the bottom joint (--quick; the fit cut short)."""
    client, eps, tmp_path = daemon
    enabled_and_still(client, eps)
    out = tmp_path / "experiments"
    done = subprocess.run([sys.executable, "-m", "daemon.client.ctl", "identify", "bottom", "--quick", "--out",
                           str(out), "--population", "4", "--generations", "1"], cwd=tmp_path, env=endpoint_env(eps),
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return out / "experiments.mcap"


def test_ctrl_c_while_identify_fits_a_recording_says_what_it_stopped(daemon, experiments):
    _, eps, tmp_path = daemon
    out = tmp_path / "fitted"
    done = interrupted(eps, tmp_path, "identify", "bottom", "--from", str(experiments), "--out", str(out),
                       when=lambda printed: any(line.startswith("fit: generation") for line in printed))
    assert one_line(done) == (f"interrupted: the fit of bottom to {experiments} stopped; nothing was written "
                              f"(`pneumactl identify bottom --from {experiments}` fits it again)")
    assert not (out / "rig.toml").exists()


def test_ctrl_c_to_an_evaluations_process_group_ends_it_with_one_line_and_no_workers_left(tmp_path):
    """A terminal's Ctrl-C reaches pneumactl, the evaluation and its pool's workers alike: the
    workers ignore it and are ended by the evaluation, which says in one line what it stopped
    (44 lines of the workers' tracebacks before); exit 130."""
    proc = subprocess.Popen([sys.executable, "-m", "daemon.client.ctl", "evaluate", "--all", "--plants", "thesis",
                             "--jobs", "2", "--out", str(tmp_path / "evaluation")], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=restore_sigint)
    deadline = time.monotonic() + 120.0
    while (evaluation := child_process(proc.pid, "evaluation")) is None or child_process(evaluation, "evaluation") \
            is None:  # until the pool's workers run
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.1)
    worker = child_process(evaluation, "evaluation")
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert err.strip().splitlines() == ["interrupted: the evaluation stopped; its results are written only once "
                                        "every case has run"], err
    assert not running(worker) and not running(evaluation)


TAKEN_THEN_CTRL_C = """
import os, signal, sys
from pathlib import Path
from daemon.client import payload_routine
from daemon.client.client import Client, Interrupted
client = Client(timeout=5.0)
take = client.acquire_lease
def taken_then_ctrl_c(*args, **kwargs):
    granted = take(*args, **kwargs)
    print(granted["ttl_s"], flush=True)
    os.kill(os.getpid(), signal.SIGINT)
    return granted
client.acquire_lease = taken_then_ctrl_c
try:
    payload_routine.run(client, Path(sys.argv[1]), True)
except (KeyboardInterrupt, Interrupted):
    sys.exit(130)
"""


def test_ctrl_c_while_a_routine_takes_its_lease_hands_the_lease_back(daemon):
    """A lease taken and then never renewed lapses and trips the enabled arm ("lease lost"):
    a Ctrl-C that comes while the routine takes it is held back until it is, and the lease
    handed back with the rest."""
    client, eps, tmp_path = daemon
    enabled_and_still(client, eps)
    done = subprocess.run([sys.executable, "-c", TAKEN_THEN_CTRL_C, str(tmp_path / "never.json")], cwd=tmp_path,
                          env=endpoint_env(eps), capture_output=True, text=True, timeout=120, preexec_fn=restore_sigint)
    assert done.returncode == 130, done.stderr
    time.sleep(2 * float(done.stdout.split()[0]))  # the lease's time to lapse, twice
    status = client.status()
    assert status["state"] == "enabled" and status["trips"] == 0 and not status["lease_held"], status["cause"]


@pytest.mark.parametrize("command", ["status", "describe", "controller list"])
def test_pneumactl_piped_into_a_reader_that_stops_ends_quietly(daemon, command):
    """``pneumactl status | head`` ended in a BrokenPipeError traceback: piped into a reader
    that has gone (``true`` reads nothing), it ends as a Unix tool does, silently, with the
    status a SIGPIPE gives (128 + 13); into ``head -n 1``, with its first line."""
    _, eps, tmp_path = daemon
    pneumactl = f"{sys.executable} -m daemon.client.ctl {command}"
    gone = subprocess.run(["bash", "-c", f"{pneumactl} | true; exit ${{PIPESTATUS[0]}}"], cwd=tmp_path,
                          env=endpoint_env(eps), capture_output=True, text=True, timeout=120)
    assert (gone.returncode, gone.stderr) == (128 + signal.SIGPIPE, "")
    head = subprocess.run(["bash", "-c", f"{pneumactl} | head -n 1"], cwd=tmp_path, env=endpoint_env(eps),
                          capture_output=True, text=True, timeout=120)
    assert head.stdout == "{\n" and head.stderr == ""
