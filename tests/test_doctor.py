"""``pneumactl doctor`` on this machine: what it finds about the PC (real-time scheduling, CPUs,
load, a short latency run), the endpoints pneumactl would use (here always private ones,
through PNEUMAD_*), the recording directory and the key files, each with what to do; exit 1
when a finding blocks real use. Also as ``--no-rt`` and as a user without the right to
real-time scheduling, and with an endpoint another program holds (daemon/client/doctor.py)."""
import ctypes
import json
import os
import resource
import re
import socket
import subprocess

import pytest

from daemon.client.client import Client
from daemon.service import host
from daemon.testing.daemons import STOP_WAIT_S
from daemon.wire import keys
from tests import doc_blocks, doc_runs
from tests.daemons import endpoint_env, private_endpoints, real_daemon, wait_for_own_daemon
from tests.doc_blocks import BIN

pytestmark = pytest.mark.slow(seconds=60)
PR_CAPBSET_DROP = 24  # linux/prctl.h
SECTION = "When something went wrong: the journal, the timing verdict, the doctor"


def doctor(env: dict, *options: str, **run) -> tuple[int, dict[str, dict]]:
    """``pneumactl doctor --json`` (a second's latency run): its exit status and its findings by check."""
    done = subprocess.run([f"{BIN}pneumactl", "doctor", "--json", "--latency-seconds", "1", *options], env=env,
                          capture_output=True, text=True, timeout=300, **run)
    assert done.returncode in (0, 1), done.stderr
    findings = {f["check"]: f for f in json.loads(done.stdout)}
    assert all(f["status"] in ("ok", "note", "warn", "fail") for f in findings.values())
    assert all(f["todo"] for f in findings.values() if f["status"] in ("warn", "fail"))  # each says what to do
    assert done.returncode == (1 if any(f["status"] == "fail" for f in findings.values()) else 0)
    return done.returncode, findings


def check_the_machine(findings: dict) -> None:
    """What holds for this machine, whatever it is: the load and isolated CPUs it has, a latency
    verdict from a real run."""
    if host.isolated_cpus():
        assert "isolated" in findings["CPU isolation"]["found"]
    else:
        assert findings["CPU isolation"]["status"] == "warn" and "no CPU is isolated" in findings["CPU isolation"]["found"]
    assert "runnable on" in findings["load"]["found"]
    latency = findings["latency"]
    assert latency["found"].startswith("pneumad latency --seconds 1") and "wake-up p50" in latency["found"]
    verdict = re.search(r"; (GOOD|USABLE|NOT SUITABLE): ", latency["found"]).group(1)
    assert latency["status"] == {"GOOD": "ok", "USABLE": "warn", "NOT SUITABLE": "fail"}[verdict]


def test_the_doctor_examines_this_machine_and_the_running_daemon_and_fails_on_a_secret_key_others_can_read(tmp_path):
    """A --no-rt daemon on private endpoints: held by it and answering; its loop's scheduling
    named; its recording directory's disk; a secret key of mode 0644 fails (exit 1), one of
    0600 does not. Then systemd/README.md's doctor line, as written, against the same daemon."""
    key_dir = tmp_path / "keys"
    key_dir.mkdir()
    keys.new_client_pair(str(key_dir), "kept")
    _, exposed = keys.new_client_pair(str(key_dir), "exposed")
    os.chmod(exposed, 0o644)
    daemon, eps = real_daemon(tmp_path)
    env = endpoint_env(eps)
    try:
        with Client(**eps, timeout=20.0) as client:
            wait_for_own_daemon(client, daemon)
        code, findings = doctor(env, "--keys", str(key_dir))
        line, = doc_blocks.commands("systemd/README.md", SECTION, match=r"pneumactl doctor")
        done = doc_runs.run(line, tmp_path, env=env, timeout=300)
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    assert code == 1
    rt = findings["real-time scheduling"]
    assert rt["status"] == "warn" and "the running daemon's loop: SCHED_OTHER 0" in rt["found"]
    check_the_machine(findings)
    for name, address in eps.items():
        held = findings[f"{name} endpoint {address}"]
        assert held["status"] == "ok" and f"held by pneumad pid {daemon.pid}" in held["found"], held
        assert "which answers ping" in held["found"]
    recordings = findings[f"recording directory {tmp_path / 'recordings'}"]  # the daemon's, as it said
    assert "MB free on its disk" in recordings["found"]
    assert findings[f"key {exposed}"]["status"] == "fail" and f"chmod 600 {exposed}" in findings[f"key {exposed}"]["todo"]
    assert findings[f"key {key_dir / 'kept.key_secret'}"] == {
        "check": f"key {key_dir / 'kept.key_secret'}", "status": "ok", "found": "mode 0600", "todo": ""}
    # The document's line: the same findings in words, one a line, each with what to do.
    assert done.returncode in (0, 1), done.explain()
    assert "real-time scheduling: " in done.stdout and "latency: pneumad latency --seconds 1" in done.stdout
    assert f"command endpoint {eps['command']}: held by pneumad pid {daemon.pid}" in done.stdout
    assert done.stdout.rstrip().splitlines()[-1].startswith("doctor: ")


def drop_sys_nice() -> None:
    """In the child before exec: CAP_SYS_NICE out of its bounding set, so the program it
    becomes has no right to real-time scheduling, root or not (its RLIMIT_RTPRIO: 0)."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_CAPBSET_DROP, host.CAP_SYS_NICE, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP, CAP_SYS_NICE)")
    resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))


def test_as_no_rt_and_without_the_right_to_real_time_scheduling_the_doctor_says_so_and_why(tmp_path):
    """``--no-rt``: not asked for. Without CAP_SYS_NICE and with RLIMIT_RTPRIO 0 (a lab member's
    login, not the service's): refused, and why, with what to do."""
    env = endpoint_env(private_endpoints(tmp_path))
    _, findings = doctor(env, "--no-rt", "--keys", str(tmp_path / "no-keys"))
    assert findings["real-time scheduling"]["status"] == "warn"
    assert findings["real-time scheduling"]["found"].startswith("not asked for (--no-rt)")
    assert findings["latency"]["found"].startswith("pneumad latency --seconds 1 --no-rt")
    assert findings["keys"]["status"] == "note"
    for name, address in private_endpoints(tmp_path).items():
        assert findings[f"{name} endpoint {address}"]["status"] == "note"  # free: no daemon
    check_the_machine(findings)
    _, unprivileged = doctor(env, "--keys", str(tmp_path / "no-keys"), preexec_fn=drop_sys_nice)
    rt = unprivileged["real-time scheduling"]
    assert rt["status"] == "warn" and rt["found"].startswith("SCHED_FIFO 80 refused (Operation not permitted): ")
    assert "CAP_SYS_NICE, RLIMIT_RTPRIO 0 below priority 80" in rt["found"] and "limits.conf" in rt["todo"]


def test_an_endpoint_another_program_holds_blocks_real_use(tmp_path):
    """A program that is not pneumad listens where pneumad's command socket would be."""
    eps = private_endpoints(tmp_path)
    squatter = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    squatter.bind(eps["command"].removeprefix("ipc://"))
    squatter.listen()
    try:
        code, findings = doctor(endpoint_env(eps), "--keys", str(tmp_path / "no-keys"))
    finally:
        squatter.close()
    held = findings[f"command endpoint {eps['command']}"]
    assert code == 1 and held["status"] == "fail"
    assert f"held by pid {os.getpid()} (" in held["found"] and "not pneumad: pneumad cannot bind it" in held["found"]
    assert "PNEUMAD_COMMAND" in held["todo"]
