"""Real ``pneumad run`` processes on private ipc endpoints under a directory of the caller's
(the simulated rig unless the options say otherwise), for the benches and the tests."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ENDPOINTS = ("command", "control", "telemetry")
# How long a test or bench waits for a process it started to stop [s]: about 1 s when quiet,
# over 10 s beside two CPU hogs and a suite's other daemons (the lab PC's unit gives its
# real-time daemon TimeoutStopSec=5s).
STOP_WAIT_S = 60.0
# ``python -c LAUNCH PARENT_PID MODULE ARGS...``: have Linux send this process SIGTERM when the
# thread that started it ends (hal.process.die_with_parent; an exec keeps it), then become
# ``python -m MODULE ARGS...``, the same pid. A test run killed or interrupted (an xdist worker
# gone without its teardown) leaves no daemon cycling on after it.
LAUNCH = """import os, signal, sys
from hal.process import die_with_parent
die_with_parent(signal.SIGTERM)
if os.getppid() != int(sys.argv[1]):
    sys.exit("the process that started this daemon had already ended")
os.execv(sys.executable, [sys.executable, "-m", *sys.argv[2:]])
"""


def spawn(directory, *options: str, module: str = "daemon.main", **popen) -> tuple[subprocess.Popen, dict[str, str]]:
    """``python -m <module> run`` with ``options``, its sockets as ipc files in ``directory``
    and its recordings in ``directory/recordings`` (unless the options name another), ended
    (SIGTERM) when the calling thread ends; the process and its endpoints (name -> address)."""
    if "--record-dir" not in options:
        options = (*options, "--record-dir", str(Path(directory) / "recordings"))
    eps = private_endpoints(directory)
    daemon = subprocess.Popen([sys.executable, "-c", LAUNCH, str(os.getpid()), module, "run", "--log-level", "WARNING",
                               *options, *sum(([f"--{k}", v] for k, v in eps.items()), [])], **popen)
    return daemon, eps


def private_endpoints(directory) -> dict[str, str]:
    """ipc endpoints in ``directory``: nobody else's daemon can be on them."""
    return {name: f"ipc://{directory}/{name}" for name in ENDPOINTS}
