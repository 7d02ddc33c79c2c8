"""Real daemon processes for tests: ``pneumad run`` on the simulated rig, no real-time set-up,
on private ipc endpoints."""
from __future__ import annotations

import subprocess
from pathlib import Path

from daemon.testing import daemons
from hal import config

TOLERANT_STALL = "stall_after_s = 0.5  "


def tolerant_rig_text() -> str:
    """The built-in rig with a stall limit of 0.5 s instead of its 50 ms. The test machine is
    a virtual one whose hypervisor stops even a SCHED_FIFO thread for up to 45 ms now and then
    (cyclictest on the idle machine: docs/benchmarks.md, "CURVE on every socket"), so a real
    daemon run for seconds trips now and then by the hypervisor's hand, as the rig file tells
    it to; the tests about stalls set their own limits."""
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
    ``python -m <module>`` (``module``: default ``daemon.main``)."""
    if "--config" not in options:
        options = (*options, "--config", str(tolerant_rig(tmp_path)))
    return daemons.spawn(tmp_path, "--no-rt", *options, **popen)


def running(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False
