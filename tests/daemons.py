"""Real daemon processes for tests: ``pneumad run`` on the simulated rig, no real-time set-up,
on private ipc endpoints; and the check that the daemon answering is the test's own."""
from __future__ import annotations

import os
import subprocess
import time
from contextlib import contextmanager
from pathlib import Path

from daemon.client.client import ENDPOINT_VARIABLES, Client
from daemon.testing import daemons
from daemon.testing.daemons import private_endpoints  # noqa: F401  (the tests' own import of it)
from daemon.testing.ports import free_tcp_ports  # noqa: F401  (the tests' own import of it)
from hal import config

TOLERANT_STALL = "stall_after_s = 5.0  "


def tolerant_rig_text() -> str:
    """The built-in rig with a stall limit of 5 s instead of its 50 ms. The test machine is
    a virtual one whose hypervisor stops even a SCHED_FIFO thread for up to 45 ms now and then
    (cyclictest on the idle machine: docs/benchmarks.md, "CURVE on every socket"), and the
    daemons of a test run beside other work (two CPU hogs held a --no-rt loop for 1.3 s), so a
    real daemon run for seconds would trip by the machine's hand, as the rig file tells it to;
    the tests about stalls set their own limits (tests/test_stall.py, test_loop's stall tests)."""
    text = config.load().source.replace("stall_after_s = 0.05 ", TOLERANT_STALL)
    assert TOLERANT_STALL in text
    return text


def tolerant_rig(tmp_path) -> Path:
    path = Path(tmp_path) / "tolerant-rig.toml"
    path.write_text(tolerant_rig_text())
    return path


def real_daemon(tmp_path, *options: str, **popen) -> tuple[subprocess.Popen, dict[str, str]]:
    """A real ``pneumad run`` (simulated rig, stall-tolerant unless ``--config`` says
    otherwise, recording into ``tmp_path/recordings``, no real-time set-up) on private ipc endpoints, started with
    ``python -m <module>`` (``module``: default ``daemon.main``). It sleeps to each deadline
    instead of spinning its last 200 us (``--spin-us 0``): the spin sharpens the wake-up on a
    lab PC, which no test asserts, and cost the suite a fifth of a core per running daemon
    (about 80 of them): a tenth of the suite's CPU time."""
    if "--config" not in options:
        options = (*options, "--config", str(tolerant_rig(tmp_path)))
    if "--spin-us" not in options:
        options = (*options, "--spin-us", "0")
    return daemons.spawn(tmp_path, "--no-rt", *options, **popen)


def running(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def endpoint_env(eps: dict[str, str], **extra: str) -> dict[str, str]:
    """This process's environment with PNEUMAD_COMMAND/CONTROL/TELEMETRY set to ``eps``: the
    client and pneumactl started with it talk to the test's daemon only."""
    return {**os.environ, **{ENDPOINT_VARIABLES[name]: ep for name, ep in eps.items()}, **extra}


def wait_for_own_daemon(client: Client, daemon: subprocess.Popen, limit_s: float = 60.0) -> dict:
    """Ping until ``daemon`` answers, and check that it is the daemon that answered (its pid in
    the reply): never a daemon someone else started. Returns the ping's ``daemon`` map."""
    deadline = time.monotonic() + limit_s
    while True:
        assert daemon.poll() is None, f"pneumad exited with {daemon.returncode}"
        try:
            answer = client.call("ping", timeout=1.0)["daemon"]
            break
        except TimeoutError:
            assert time.monotonic() < deadline, f"pneumad did not answer within {limit_s} s"
    assert answer["pid"] == daemon.pid, f"another daemon answered: {answer} (ours: pid {daemon.pid})"
    return answer


@contextmanager
def answering_daemon(tmp_path):
    """A real daemon (:func:`real_daemon`) that has answered, and a client of it: ``(client,
    endpoints, tmp_path)``; the daemon stopped on the way out (a module fixture's body)."""
    proc, eps = real_daemon(tmp_path)
    client = Client(**eps, timeout=5.0)
    try:
        wait_for_own_daemon(client, proc)
        yield client, eps, tmp_path
    finally:
        client.close()
        proc.terminate()
        proc.wait(daemons.STOP_WAIT_S)

