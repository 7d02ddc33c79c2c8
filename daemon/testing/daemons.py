"""Real ``pneumad run`` processes on private ipc endpoints under a directory of the caller's
(the simulated rig unless the options say otherwise), for the benches and the tests."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ENDPOINTS = ("command", "control", "telemetry")


def spawn(directory, *options: str, module: str = "daemon.main", **popen) -> tuple[subprocess.Popen, dict[str, str]]:
    """``python -m <module> run`` with ``options``, its sockets as ipc files in ``directory``
    and its recordings in ``directory/recordings`` (unless the options name another); the
    process and its endpoints (name -> address)."""
    if "--record-dir" not in options:
        options = (*options, "--record-dir", str(Path(directory) / "recordings"))
    eps = private_endpoints(directory)
    daemon = subprocess.Popen([sys.executable, "-m", module, "run", "--log-level", "WARNING", *options,
                               *sum(([f"--{k}", v] for k, v in eps.items()), [])], **popen)
    return daemon, eps


def private_endpoints(directory) -> dict[str, str]:
    """ipc endpoints in ``directory``: nobody else's daemon can be on them."""
    return {name: f"ipc://{directory}/{name}" for name in ENDPOINTS}
