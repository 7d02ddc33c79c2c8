"""What this PC grants the loop: real-time scheduling (and why it is or is not granted),
isolated CPUs, load. ``pneumad`` says it in one line at start (:func:`start_verdict`), and
``pneumactl doctor`` (:mod:`daemon.client.doctor`) reads the same facts, each with what to do.
Read at start-up or on request, never in a cycle."""
from __future__ import annotations

import logging
import os
import resource
import threading

CAP_SYS_NICE = 23  # linux/capability.h
ISOLATED = "/sys/devices/system/cpu/isolated"
OVERLOADED_PER_CPU = 1.0  # runnable tasks a CPU (the 1-minute load average): past this the loop waits its turn


def cpu_list(text: str) -> list[int]:
    """A kernel CPU list (``1,3-5``) as CPU numbers."""
    cpus = []
    for part in text.strip().split(","):
        if part:
            low, _, high = part.partition("-")
            cpus.extend(range(int(low), int(high or low) + 1))
    return cpus


def isolated_cpus(path: str = ISOLATED) -> list[int]:
    """The CPUs the kernel keeps other work off (``isolcpus=``); [] for none, or unknown."""
    try:
        with open(path) as f:
            return cpu_list(f.read())
    except (OSError, ValueError):
        return []


def has_capability(bit: int, status: str = "/proc/self/status") -> bool:
    """Whether this process's effective capabilities hold ``bit``."""
    try:
        with open(status) as f:
            for line in f:
                if line.startswith("CapEff:"):
                    return bool(int(line.split()[1], 16) >> bit & 1)
    except (OSError, ValueError):
        pass
    return False


def realtime_grant(priority: int = 80) -> dict:
    """Whether SCHED_FIFO at ``priority`` is granted here, and why: a trial in a thread of its own
    (Linux schedules threads: the trial's thread alone changes class, and ends), with the facts
    that decide it (root, CAP_SYS_NICE, RLIMIT_RTPRIO); ``why`` in words."""
    soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
    facts = {"root": os.geteuid() == 0, "cap_sys_nice": has_capability(CAP_SYS_NICE),
             "rlimit_rtprio": None if soft == resource.RLIM_INFINITY else soft}
    outcome: list[str] = []

    def trial() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            outcome.append("")
        except OSError as exc:
            outcome.append(exc.strerror or str(exc))

    thread = threading.Thread(target=trial, name="rt-trial")
    thread.start()
    thread.join()
    refusal = outcome[0] if outcome else "the trial did not run"
    rlimit = facts["rlimit_rtprio"]
    allowed_by = "root" if facts["root"] and facts["cap_sys_nice"] else "CAP_SYS_NICE" if facts["cap_sys_nice"] else \
        "RLIMIT_RTPRIO unlimited" if rlimit is None else f"RLIMIT_RTPRIO {rlimit}" if rlimit >= priority else ""
    if not refusal:
        why = f"granted (by {allowed_by or 'the system'})"
    elif allowed_by:
        why = (f"refused ({refusal}) although {allowed_by} allows it: a cgroup without a real-time budget (a kernel "
               f"with CONFIG_RT_GROUP_SCHED, systemd/README.md)")
    else:
        who = "root without CAP_SYS_NICE" if facts["root"] else "not root, no CAP_SYS_NICE"
        why = f"refused ({refusal}): {who}, RLIMIT_RTPRIO {rlimit} below priority {priority}"
    return {"granted": not refusal, "priority": priority, "why": why, **facts}


def start_verdict(scheduling: dict, no_rt: bool) -> tuple[int, str]:
    """``pneumad``'s line at start, once its real-time set-up is done (``scheduling``: what the
    loop runs with, :func:`daemon.service.realtime.describe`): whether real-time scheduling was
    granted, the CPUs and whether they are isolated, the load; WARNING where the loop's timing
    is at risk, else INFO. (Its level, its text.)"""
    fifo = scheduling["policy"] in ("SCHED_FIFO", "SCHED_RR")
    rt = f"{scheduling['policy']} {scheduling['priority']}" if fifo else \
        "no real-time scheduling (--no-rt)" if no_rt else "real-time scheduling refused (see the warning above)"
    isolated = isolated_cpus()
    cpus = scheduling["cpus"]
    on = f"CPUs {','.join(map(str, cpus))}" + (" (isolated)" if isolated and set(cpus) <= set(isolated) else
                                               ", none isolated" if not isolated else
                                               f", not the isolated {','.join(map(str, isolated))}")
    average, count = os.getloadavg()[0], os.cpu_count() or 1
    overloaded = average > OVERLOADED_PER_CPU * count
    busy = f"load {average:.1f} on {count} CPUs" + (" (overloaded)" if overloaded else "")
    if fifo and not overloaded:
        return logging.INFO, f"this PC: {rt} on {on}; {busy}: fit to run"
    return logging.WARNING, (f"this PC: {rt} on {on}; {busy}: the loop's timing is at risk (the timing event and "
                             f"`pneumactl status` say when it is degraded; `pneumactl doctor` says what to do)")
