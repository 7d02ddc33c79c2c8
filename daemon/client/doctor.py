"""``pneumactl doctor``: is this PC fit to run pneumad, and what to do where it is not.

It looks at what the loop would be granted (real-time scheduling, and why it is or is not:
:mod:`daemon.service.host`), the CPUs (isolated ones, those the running daemon's loop is on),
the load, a short ``pneumad latency`` run's verdict, who holds the daemon's endpoints (the
ones pneumactl would use: ``--command`` ... or ``PNEUMAD_COMMAND`` ..., never others), the
recording directory's free space and the key files' permissions. Each finding is ``ok``,
``note``, ``warn`` (the loop's timing, or a run's validity, is at risk) or ``fail`` (something
blocks real use: the daemon cannot bind, records nothing, or its keys are readable by others);
each says what to do. The exit status is 1 when a finding fails, else 0.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import asdict, dataclass

from daemon.wire import endpoint_holders as sockets
from daemon.client.client import Client, KeyRefused, RemoteError
from daemon.service import host
from daemon.wire.keys import KeyFileError

STATUSES = ("ok", "note", "warn", "fail")
MIN_FREE_MB = 200.0  # pneumad's --record-min-free-mb default: below it recordings end and record.start is refused
ROOMY_MB = 2048.0  # pneumad's --record-max-mb default: one recording's most
KEY_DIRS = ("~/.config/pneumad", "/etc/pneumad/keys")  # where `pneumactl keys new` and the service keep keys
BUSY_PER_CPU = 0.7  # the 1-minute load a CPU past which the loop starts to wait its turn now and then


@dataclass(frozen=True)
class Finding:
    check: str
    status: str  # one of STATUSES
    found: str
    todo: str = ""  # what to do (empty where nothing is to be done)


def add_parser(sub) -> None:
    """``pneumactl doctor``'s options (the endpoints and keys are pneumactl's own)."""
    d = sub.add_parser("doctor", help="is this PC fit to run pneumad: scheduling, CPUs, load, latency, endpoints, "
                                      "disk, keys; each finding with what to do (exit 1 when one blocks real use)")
    d.add_argument("--no-rt", action="store_true", help="judge it as `pneumad --no-rt` runs: no real-time scheduling")
    d.add_argument("--rt-priority", type=int, default=80, help="the SCHED_FIFO priority pneumad asks for (default 80)")
    d.add_argument("--latency-seconds", type=float, default=3.0,
                   help="how long `pneumad latency` runs (default 3; 0: not run)")
    d.add_argument("--record-dir", default=None,
                   help="the recording directory (default: the running daemon's, else pneumad's default)")
    d.add_argument("--keys", action="append", default=None, metavar="DIR",
                   help=f"where key files are, repeatable (default: {', '.join(KEY_DIRS)}, and --key)")
    d.add_argument("--json", action="store_true", help="the findings as JSON")


def run(args: argparse.Namespace) -> int:
    """Every check, printed; 1 when one fails."""
    findings = examine(args)
    if args.json:
        print(json.dumps([asdict(f) for f in findings], indent=2))
    else:
        print(report(findings))
    return 1 if any(f.status == "fail" for f in findings) else 0


def examine(args: argparse.Namespace) -> list[Finding]:
    daemon, endpoints, said = _ask_daemon(args)
    findings = [*said, scheduling(args.no_rt, args.rt_priority, daemon.get("status")),
                isolation(daemon.get("status")), load()]
    if args.latency_seconds > 0:
        findings.append(latency(args.latency_seconds, args.no_rt, args.rt_priority))
    findings += [endpoint(name, address, daemon.get("ping")) for name, address in endpoints.items()]
    findings.append(recordings(args.record_dir or daemon.get("record_dir")))
    findings += keys(args.keys or list(KEY_DIRS), args.key or os.environ.get("PNEUMAD_KEY"))
    return findings


def report(findings: list[Finding]) -> str:
    lines = []
    for f in findings:
        lines.append(f"{f.status:5} {f.check}: {f.found}")
        if f.todo:
            lines.append(f"      -> {f.todo}")
    blocking = [f.check for f in findings if f.status == "fail"]
    warned = sum(f.status == "warn" for f in findings)
    lines.append(f"doctor: {len(blocking)} finding{'s block' if len(blocking) != 1 else ' blocks'} real use "
                 f"({', '.join(blocking)})" if blocking else
                 f"doctor: nothing blocks real use; {warned} warning{'s' if warned != 1 else ''}")
    return "\n".join(lines)


def _ask_daemon(args) -> tuple[dict, dict[str, str], list[Finding]]:
    """The daemon on pneumactl's endpoints, if one answers: its ping, status and recording
    directory; the endpoints; a finding if the keys given cannot be used."""
    try:
        client = Client(args.command, args.control, args.telemetry, timeout=min(args.timeout, 2.0),
                        key_file=args.key, server_key_file=args.server_key)
    except KeyFileError as exc:
        return {}, {}, [Finding("keys", "fail", f"pneumactl's key cannot be used: {exc}",
                                "give the .key_secret file (--key FILE or PNEUMAD_KEY)")]
    answers: dict = {}
    try:
        answers["ping"] = client.call("ping", control=True)
        answers["status"] = client.status()
        answers["record_dir"] = client.record_list()["directory"]
    except (TimeoutError, KeyRefused, RemoteError):
        pass
    finally:
        client.close()
    return answers, dict(client.endpoints), []


def scheduling(no_rt: bool, priority: int, status: dict | None) -> Finding:
    """Whether SCHED_FIFO is granted here and why; the running daemon's loop's, if one answers."""
    running = ""
    if status is not None:
        s = status["scheduling"]
        running = f"; the running daemon's loop: {s['policy']} {s['priority']} on CPUs {s['cpus']}"
    if no_rt:
        return Finding("real-time scheduling", "warn", f"not asked for (--no-rt): the loop takes its turn with every "
                                                       f"other process{running}",
                       "run pneumad without --no-rt, as root or with LimitRTPRIO (systemd/pneumad.service)")
    grant = host.realtime_grant(priority)
    if status is not None and status["scheduling"]["policy"] == "SCHED_OTHER":
        return Finding("real-time scheduling", "warn", f"SCHED_FIFO {priority} {grant['why']}{running}: real-time "
                                                       f"scheduling was not asked for or not granted to it",
                       "its log's first lines say why; start it without --no-rt (systemd/README.md)")
    if grant["granted"]:
        return Finding("real-time scheduling", "ok", f"SCHED_FIFO {priority} {grant['why']}{running}")
    todo = "systemd/README.md, \"Real-time scheduling, and when it is refused\": give the cgroup a real-time budget" \
        if "cgroup" in grant["why"] else \
        "run pneumad as the service (LimitRTPRIO=95 and CAP_SYS_NICE in systemd/pneumad.service), or as root, or " \
        "allow this user rtprio 95 in /etc/security/limits.conf"
    return Finding("real-time scheduling", "warn", f"SCHED_FIFO {priority} {grant['why']}{running}", todo)


def isolation(status: dict | None) -> Finding:
    """Isolated CPUs (isolcpus), and whether the running daemon's loop is on them."""
    isolated = host.isolated_cpus()
    loop_cpus = status["scheduling"]["cpus"] if status is not None else None
    todo = "add isolcpus=N nohz_full=N to the kernel command line (N: a CPU for the loop), reboot, and run pneumad " \
           "--cpus N"
    if not isolated:
        return Finding("CPU isolation", "warn", f"no CPU is isolated ({host.ISOLATED} is empty): the loop shares its "
                                                f"CPU with everything else", todo)
    listed = ",".join(map(str, isolated))
    if loop_cpus is None:
        return Finding("CPU isolation", "ok", f"CPUs {listed} isolated (no daemon answers: give it --cpus {listed})")
    if set(loop_cpus) <= set(isolated):
        return Finding("CPU isolation", "ok", f"CPUs {listed} isolated; the daemon's loop runs on {loop_cpus}")
    return Finding("CPU isolation", "warn", f"CPUs {listed} isolated, but the daemon's loop runs on {loop_cpus}",
                   f"restart pneumad with --cpus {isolated[-1]}")


def load() -> Finding:
    average, count = os.getloadavg()[0], os.cpu_count() or 1
    found = f"{average:.1f} runnable on {count} CPUs (1-minute average, {average / count:.2f} a CPU)"
    if average > host.OVERLOADED_PER_CPU * count:
        return Finding("load", "warn", f"{found}: overloaded, the loop waits its turn and runs made now are not "
                                       f"valid at its rate (the timing event says when)",
                       "stop other work (`top` shows what runs), or give the loop real-time scheduling and an "
                       "isolated CPU")
    if average > BUSY_PER_CPU * count:
        return Finding("load", "note", f"{found}: busy", "keep other work off this PC during runs")
    return Finding("load", "ok", found)


def latency(seconds: float, no_rt: bool, priority: int) -> Finding:
    """A short ``pneumad latency`` run (the loop on the simulator, real time) and its verdict."""
    command = [sys.executable, "-m", "daemon.main", "latency", "--seconds", f"{seconds:g}", "--rt-priority",
               str(priority), *(["--no-rt"] if no_rt else [])]
    shown = f"pneumad latency --seconds {seconds:g}" + (" --no-rt" if no_rt else "")
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=seconds + 180.0)
    except subprocess.TimeoutExpired:
        return Finding("latency", "warn", f"{shown} did not finish within {seconds + 180:g} s",
                       "the PC is too busy even to start it: stop other work")
    verdict = re.search(r"^verdict: (.*)$", done.stdout, re.M)
    figures = re.search(r"^wake-up latency\s+us: (.*)$", done.stdout, re.M)
    if done.returncode != 0 or verdict is None:
        return Finding("latency", "warn", f"{shown} failed (exit {done.returncode}): {done.stderr.strip()[-300:]}",
                       "run it by hand to see why")
    found = f"{shown}: wake-up {figures.group(1) if figures else '?'}; {verdict.group(1)}"
    if verdict.group(1).startswith("GOOD"):
        return Finding("latency", "ok", found)
    if verdict.group(1).startswith("USABLE"):
        return Finding("latency", "warn", found, "qualify it for minutes: pneumad latency --seconds 120 --cpus N "
                                                 "(systemd/README.md)")
    return Finding("latency", "fail", found, "this PC cannot hold a 1 ms loop now: stop other work, give the loop "
                                             "real-time scheduling and an isolated CPU, or a PREEMPT_RT kernel")


def _is_pneumad(command: str) -> bool:
    """Whether a command line is pneumad's: its program (``pneumad``, ``python -m daemon.main``) or
    its messenger process; not any program whose path happens to hold the word (a checkout in
    ``/tmp/pneumad-ci`` runs its tests from there)."""
    words = command.split()
    return any(os.path.basename(w) == "pneumad" or w == "daemon.main" or w.startswith("daemon.messenger")
               for w in words[:6])


def endpoint(name: str, address: str, ping: dict | None) -> Finding:
    """Who holds ``address``: the daemon that answers, another program (pneumad cannot bind it),
    or nobody."""
    check = f"{name} endpoint {address}"
    daemon = ping["daemon"] if ping is not None else None
    held = sockets.holders(sockets.listening_inodes(address))
    if not held:
        if daemon is not None:
            return Finding(check, "ok", f"pneumad pid {daemon['pid']} answers (its socket is not one this machine "
                                        f"lists: another host, or another network namespace)")
        scheme = address.partition("://")[0]
        return Finding(check, "note", "free: no daemon runs on it" if scheme in ("tcp", "ipc") else
                       f"not checked ({scheme})", "start pneumad (or point pneumactl at yours: --command ..., "
                                                   "PNEUMAD_COMMAND ...)")
    owners = ", ".join(map(str, held))
    if daemon is not None and any(h.pid in (daemon["pid"], None) or sockets.parent_of(h.pid) == daemon["pid"]
                                  for h in held):
        return Finding(check, "ok", f"held by pneumad pid {daemon['pid']} ({owners}), which answers ping "
                                    f"(version {ping['version']})")
    if any(h.pid is None or _is_pneumad(h.command) for h in held):
        return Finding(check, "warn", f"held by {owners}, a pneumad that does not answer ping",
                       "`pneumactl status`; a stalled or a keyed daemon (--key) does not answer; its log says why")
    return Finding(check, "fail", f"held by {owners}, not pneumad: pneumad cannot bind it",
                   f"stop that program, or run pneumad and pneumactl on another endpoint (--{name}, "
                   f"PNEUMAD_{name.upper()})")


def recordings(directory: str | None) -> Finding:
    """Free space where the daemon records (pneumad's own default when no daemon answers)."""
    directory = directory or os.path.join(os.environ.get("STATE_DIRECTORY", "").split(":")[0], "recordings")
    existing = os.path.abspath(directory)
    while not os.path.isdir(existing) and existing != os.path.dirname(existing):
        existing = os.path.dirname(existing)
    free_mb = shutil.disk_usage(existing).free / 1e6
    check = f"recording directory {directory}"
    found = f"{free_mb:,.0f} MB free on its disk" + ("" if existing == os.path.abspath(directory) else
                                                     f" ({existing}; the directory is made at the first recording)")
    if free_mb < MIN_FREE_MB:
        return Finding(check, "fail", f"{found}: below pneumad's {MIN_FREE_MB:g} MB, recordings end and record.start "
                                      f"is refused", "free space, or record elsewhere (pneumad --record-dir DIR)")
    if free_mb < ROOMY_MB:
        return Finding(check, "warn", f"{found}: less than one recording may take ({ROOMY_MB:g} MB)",
                       "free space, or record elsewhere (pneumad --record-dir DIR)")
    return Finding(check, "ok", found)


def keys(directories: list[str], key_file: str | None) -> list[Finding]:
    """Every secret key file (``*.key_secret``) found: readable by its owner alone (0600)."""
    found = {f for d in directories
             for f in glob.glob(os.path.join(os.path.expanduser(d), "**", "*.key_secret"), recursive=True)}
    files = sorted(found | ({key_file} if key_file else set()))
    if not files:
        return [Finding("keys", "note", f"no secret key files in {', '.join(directories)}",
                        "a daemon without keys serves loopback only; `pneumad keys init` (systemd/README.md, Keys)")]
    findings = []
    for path in files:
        try:
            mode = os.stat(path).st_mode & 0o777
        except OSError as exc:
            findings.append(Finding(f"key {path}", "fail", f"cannot be read: {exc.strerror}", "give the right file"))
            continue
        if mode & 0o077:
            findings.append(Finding(f"key {path}", "fail", f"mode {mode:04o}: others can read the secret key",
                                    f"chmod 600 {path} (and, if others did read it, revoke it and make another)"))
        else:
            findings.append(Finding(f"key {path}", "ok", f"mode {mode:04o}"))
    return findings
