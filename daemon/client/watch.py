"""``pneumactl watch``: the daemon at a glance, redrawn in place (rich) in a terminal.

State and its cause, the controller and the running reference with the time it has left,
the lease holder, per joint the angle, set-point, error and V_MV with a bar over the joint's
output range (``safe state`` instead outside ``enabled``, where the safe state is written and
no V_MV is; nor is there a tracking error then: the set-point is the last reference's, which
nothing tracks, so the error shows ``-``), the output volts actually written, the loop's health from the ``stats`` topic,
faults, the daemon's recordings in progress and the last events. Piped
or redirected (no terminal), it prints one line every 100 ms instead, which a script can read.
"""
from __future__ import annotations

import math
import sys
import time
from collections import deque

from rich.console import Group
from rich.live import Live
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from daemon.client.client import Client, RemoteError

STATE_STYLE = {"enabled": "bold green", "idle": "bold cyan", "fault": "bold red", "estop": "bold red",
               "starting": "yellow"}
BAR = 16  # characters of an output bar (the view fits 80 columns)


def watch(client: Client, seconds: float | None) -> None:
    """Until Ctrl-C (or ``seconds``): live in a terminal, lines otherwise."""
    sub = client.subscribe((b"state", b"event", b"stats"))
    end = None if seconds is None else time.monotonic() + seconds
    try:
        if sys.stdout.isatty():
            _live(client, sub, end)
        else:
            _lines(sub, end)
    except (KeyboardInterrupt, BrokenPipeError):
        pass
    finally:
        sub.close()


def _lines(sub, end) -> None:
    last_print = 0.0
    while end is None or time.monotonic() < end:
        item = sub.receive(1.0)
        if item is None:
            print("(no telemetry)", flush=True)
            continue
        topic, m = item
        if topic == "event":
            print(f"EVENT {m.get('kind')}: {m.get('cause', '')} {m.get('to', '')}", flush=True)
        elif topic == "state" and time.monotonic() - last_print >= 0.1:
            last_print = time.monotonic()
            q = "  ".join(f"{math.degrees(a):8.2f}" for a in m["angle_rad"][-1])
            e = "  ".join(f"{math.degrees(a):6.2f}" if m["mode"][-1] == "enabled" else f"{'-':>6s}"
                          for a in m["error_rad"][-1])
            print(f"{m['mode'][-1]:8s} cycle {m['cycle'][-1]:9d}  angle deg {q}   error deg {e}  "
                  f"lost {sub.lost}", flush=True)


def _live(client: Client, sub, end) -> None:
    describe = client.describe()
    view = View(describe)
    try:
        view.recordings = {a["name"]: a["who"] for a in client.record_list()["active"]}
    except RemoteError:
        pass  # a daemon that records nothing
    status_due = 0.0
    with Live(view.render(), refresh_per_second=10, screen=False) as live:
        while end is None or time.monotonic() < end:
            item = sub.receive(0.1)
            if item is not None:
                view.take(*item)
            now = time.monotonic()
            if now >= status_due:
                status_due = now + 0.5
                try:
                    view.status = client.status()
                except (TimeoutError, RemoteError) as exc:
                    view.status = {"state": "?", "cause": f"no status: {exc}"}
            view.lost = sub.lost
            live.update(view.render())


class View:
    """What the live view shows, from the telemetry and the last status."""

    def __init__(self, describe: dict):
        self.joints = describe["joints"]
        self.outputs = [o[0] for o in describe["transport"]["outputs"]]
        self.state: dict | None = None
        self.stats: dict | None = None
        self.status: dict = {}
        self.events: deque[str] = deque(maxlen=5)
        self.recordings: dict[str, str] = {}  # the daemon's recordings in progress: name -> who
        self.lost = 0

    def take(self, topic: str, m: dict) -> None:
        if topic == "state":
            self.state = m
        elif topic == "stats":
            self.stats = m
        elif topic == "event":
            if m.get("kind") == "state":
                self.events.append(f"{m.get('from')} -> {m.get('to')} ({m.get('cause', '')})")
            elif m.get("kind") == "record":
                if m.get("action") == "start":
                    self.recordings[m.get("name", "?")] = m.get("who", "")
                else:
                    self.recordings.pop(m.get("name", "?"), None)
                self.events.append(f"record {m.get('action')}: {m.get('name')} {m.get('cause', '')}".strip())
            else:
                self.events.append(f"{m.get('kind')}: {m.get('cause', '')} {m.get('to', '')}".strip())

    def render(self) -> Panel:
        s = self.status
        state = s.get("state", "?")
        head = Text.assemble(("state ", "dim"), (state, STATE_STYLE.get(state, "bold")),
                             (f"  {s['cause']}" if s.get("cause") else "", "red"),
                             ("   controller ", "dim"), str(s.get("controller", "?")),
                             ("   reference ", "dim"), str(s.get("reference") or "-"),
                             (f" ({s.get('reference_remaining_s', 0):.1f} s left)" if s.get("reference_remaining_s") else ""),
                             ("   lease ", "dim"), _holder(s))
        table = Table(expand=True, box=None)
        for name in ("joint", "angle deg", "set-point deg", "error deg", "V_MV", ""):
            table.add_column(name, justify="right" if name not in ("joint", "") else "left", no_wrap=True)
        written = Text("outputs written: waiting for telemetry", style="dim")
        if self.state is not None:
            m = self.state
            safe = m["mode"][-1] != "enabled"  # the safe state is written, whatever the controller last said
            for j, joint in enumerate(self.joints):
                u = m["u_volts"][-1][j]
                err = math.degrees(m["error_rad"][-1][j])
                table.add_row(joint["name"], f"{math.degrees(m['angle_rad'][-1][j]):8.2f}",
                              f"{math.degrees(m['setpoint_rad'][-1][j]):8.2f}",
                              Text("-", style="dim") if safe else Text(f"{err:7.2f}", style="red" if abs(err) > 2.0
                                                                         else ""),
                              Text("safe state", style="bold red") if safe else f"{u:+6.2f} V",
                              Text("") if safe else _bar(u, joint["u_min_volts"], joint["u_max_volts"]))
            written = Text("outputs written: " + "  ".join(f"{name} {v:.2f} V" for name, v in
                                                            zip(self.outputs, m["out_volts"][-1]))
                           + ("  (safe state)" if safe else ""))
        health = Text("loop: waiting for stats", style="dim")
        if self.stats is not None:
            st = self.stats
            health = Text(f"loop: wake-up p99 {st['latency_us']['p99']:.0f} us, compute p99 "
                          f"{st['compute_us']['total']['p99']:.0f} us, overruns {st['overruns']} in the last "
                          f"{st['cycles']} cycles ({st['overruns_total']} in all); telemetry lost here {self.lost}")
        faults = Text("faults: " + (", ".join(s.get("faults") or []) or "none"),
                      style="red" if s.get("faults") else "dim")
        recording = Text("recording: " + (", ".join(f"{name} ({who})" for name, who in self.recordings.items())
                                          or "none"), style="bold magenta" if self.recordings else "dim")
        events = Text("\n".join(self.events) or "no events yet", style="dim")
        return Panel(Group(head, table, written, health, faults, recording, Text("events:", style="bold"), events),
                     title="pneumad", subtitle="Ctrl-C to leave")


def _holder(status: dict) -> str:
    if not status.get("lease_held"):
        return "nobody"
    return status.get("lease_holder") or "held"


def _bar(u: float, lo: float, hi: float) -> Text:
    """V_MV on its range, zero marked: full at either limit."""
    span = hi - lo
    if span <= 0:
        return Text("")
    zero = round(-lo / span * BAR)
    at = min(max(round((u - lo) / span * BAR), 0), BAR)
    cells = [" "] * (BAR + 1)
    for i in range(min(zero, at), max(zero, at) + 1):
        cells[i] = "█"
    cells[zero] = "|"
    style = "red" if u <= lo or u >= hi else "green"
    return Text("[" + "".join(cells) + "]", style=style)
