"""Real-time set-up where the system allows it, with a clear warning where it does not.

SCHED_FIFO at a priority, mlockall, CPU affinity. None of these is required to run: a
daemon started without the privilege (not root, no LimitRTPRIO, or a kernel with RT group
scheduling under systemd, where sched_setscheduler fails with EPERM) falls back loudly to
normal scheduling rather than refusing to start.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os

MCL_CURRENT, MCL_FUTURE = 1, 2


def setup(priority: int | None, cpus: list[int] | None, lock_memory: bool) -> list[str]:
    """Apply what is asked; return one warning per thing the system refused."""
    warnings = []
    if cpus:
        try:
            os.sched_setaffinity(0, cpus)
        except OSError as exc:
            warnings.append(f"CPU affinity {cpus} not applied: {exc.strerror}")
    if lock_memory:
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
            err = ctypes.get_errno()
            warnings.append(f"mlockall failed ({errno.errorcode.get(err, err)}): memory may be paged out; "
                            f"raise LimitMEMLOCK (systemd) or run with CAP_IPC_LOCK")
    if priority is not None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except PermissionError:
            warnings.append(f"SCHED_FIFO priority {priority} not permitted (EPERM): running with normal "
                            f"scheduling. Grant CAP_SYS_NICE or LimitRTPRIO; under systemd on a kernel with "
                            f"CONFIG_RT_GROUP_SCHED, see systemd/README.md")
        except OSError as exc:
            warnings.append(f"SCHED_FIFO priority {priority} not applied: {exc.strerror}")
    return warnings


def describe() -> dict:
    """What the process actually runs with (for status and the latency report)."""
    policy = os.sched_getscheduler(0)
    names = {os.SCHED_OTHER: "SCHED_OTHER", os.SCHED_FIFO: "SCHED_FIFO", os.SCHED_RR: "SCHED_RR"}
    return {"policy": names.get(policy, str(policy)), "priority": os.sched_getparam(0).sched_priority,
            "cpus": sorted(os.sched_getaffinity(0))}
