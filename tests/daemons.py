"""Real daemon processes for tests: ``pneumad run`` on the simulated rig, no real-time set-up,
on private ipc endpoints."""
from __future__ import annotations

import subprocess
import sys


def real_daemon(tmp_path, *options: str, **popen) -> tuple[subprocess.Popen, dict[str, str]]:
    """A real ``pneumad run`` (simulated rig, no real-time set-up) on private ipc endpoints,
    started with ``python -m <module>`` (``module``: default ``daemon.main``)."""
    module = popen.pop("module", "daemon.main")
    eps = {name: f"ipc://{tmp_path}/{name}" for name in ("command", "control", "telemetry")}
    daemon = subprocess.Popen([sys.executable, "-m", module, "run", "--no-rt", "--log-level", "WARNING", *options,
                               *sum(([f"--{k}", v] for k, v in eps.items()), [])], **popen)
    return daemon, eps


def running(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False
