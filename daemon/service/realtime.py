"""Real-time set-up where the system allows it, with a clear warning where it does not.

SCHED_FIFO at a priority, mlockall, CPU affinity, and a PM QoS request that keeps the CPUs
out of deep idle states (/dev/cpu_dma_latency, as cyclictest holds it for its run: a CPU
that halts between cycles wakes late and with cold caches). None of these is required to run: a
daemon started without the privilege (not root, no LimitRTPRIO, or a kernel with RT group
scheduling under systemd, where sched_setscheduler fails with EPERM) falls back loudly to
normal scheduling rather than refusing to start.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import struct

MCL_CURRENT, MCL_FUTURE = 1, 2
CPU_DMA_LATENCY = "/dev/cpu_dma_latency"
_held = []  # PM QoS requests last while their file is open: for the life of the process


def setup(priority: int | None, cpus: list[int] | None, lock_memory: bool,
          idle_latency_us: int | None = None) -> list[str]:
    """Apply what is asked; return one warning per thing the system refused."""
    warnings = []
    if idle_latency_us is not None:
        warning = hold_idle_latency(idle_latency_us)
        if warning:
            warnings.append(warning)
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


def hold_idle_latency(us: int, path: str = CPU_DMA_LATENCY) -> str | None:
    """Ask the kernel to keep every CPU out of idle states slower than ``us`` to leave (0:
    poll rather than halt) for the life of the process; a warning if it cannot."""
    try:
        request = open(path, "wb", buffering=0)
    except OSError as exc:
        return (f"cpu_dma_latency {us} us not applied ({exc.strerror}): idle CPUs may sleep deeply and "
                f"wake the loop late; give the daemon write access to {path} (systemd/README.md)")
    try:
        request.write(struct.pack("i", us))
    except OSError as exc:
        request.close()
        return f"cpu_dma_latency {us} us not applied ({exc.strerror})"
    _held.append(request)
    return None


def describe() -> dict:
    """What the process actually runs with (for status and the latency report)."""
    policy = os.sched_getscheduler(0)
    names = {os.SCHED_OTHER: "SCHED_OTHER", os.SCHED_FIFO: "SCHED_FIFO", os.SCHED_RR: "SCHED_RR"}
    return {"policy": names.get(policy, str(policy)), "priority": os.sched_getparam(0).sched_priority,
            "cpus": sorted(os.sched_getaffinity(0))}
