"""``pneumactl watch``: the daemon at a glance, redrawn in place (rich) in a terminal.

State and its cause, the controller and the running reference with the time it has left,
the lease holder, per joint its position, set-point and error in the position's display unit
(deg for a rotary joint, mm for a linear one), each command interface with a bar over its
range (``safe state`` instead outside ``enabled``, where the safe state is written and no
command is; nor is there a tracking error then: the set-point is the last reference's, which
nothing tracks, so the error shows ``-``), the joint's further measured and commanded values
(named apart: ``p_head`` measured, ``p_head_cmd`` commanded), the rig's own sensors, the
output volts actually written, the loop's health from the ``stats`` topic, faults, the
daemon's recordings in progress and the last events. Every number, name and unit is the cycle
record's layout's (``describe``'s ``cycle_layout``): a rig with other joints or sensors is
shown as it is, with no code of its own. Piped or redirected (no terminal), it prints one line
every 100 ms instead, which a script can read.
"""
from __future__ import annotations

import sys
import time
from collections import deque

from rich.console import Group
from rich.live import Live
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from daemon.client import fields
from daemon.client.client import Client, RemoteError
from daemon.wire.cycle_layout import CycleLayout

STATE_STYLE = {"enabled": "bold green", "idle": "bold cyan", "fault": "bold red", "estop": "bold red",
               "starting": "yellow"}
BAR = 16  # characters of an output bar (the view fits 80 columns)


LARGE_ERROR = 2.0  # an error shown in red beyond this, in the position's display unit [deg or mm]


def watch(client: Client, seconds: float | None) -> None:
    """Until Ctrl-C (or ``seconds``): live in a terminal, lines otherwise."""
    sub = client.subscribe((b"state", b"event", b"stats"))
    end = None if seconds is None else time.monotonic() + seconds
    try:
        if sys.stdout.isatty():
            _live(client, sub, end)
        else:
            _lines(client, sub, end)
    except (KeyboardInterrupt, BrokenPipeError):
        pass
    finally:
        sub.close()


def line(layout: CycleLayout, m: dict, lost: int = 0) -> str:
    """The last row of a ``state`` message as one line: mode, cycle, each joint's position and
    error (``-`` outside ``enabled``) in their display units."""
    row = fields.latest(m, layout)
    enabled = row["mode"] == "enabled"
    joints = "  ".join(f"{j} {fields.shown(layout[f'{j}.position'], row[f'{j}.position'], 11)} error "
                       f"{fields.shown(layout[f'{j}.error'], row[f'{j}.error'] if enabled else None, 10)}"
                       for j in layout.owners())
    return f"{row['mode']:8s} cycle {row['cycle']:9d}  {joints}  lost {lost}"


def _lines(client: Client, sub, end) -> None:
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
            layout = client.layout(m)
            if fields.check(m, layout):
                print(line(layout, m, sub.lost), flush=True)


def _live(client: Client, sub, end) -> None:
    view = View(client.describe())
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
            if view.foreign:  # the daemon now records another layout (restarted with another rig file)
                view = view.again(client.describe())
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
    """What the live view shows, from the telemetry and the last status; every number through
    the cycle record's layout (``describe``'s, or ``layout``)."""

    def __init__(self, describe: dict, layout: CycleLayout | None = None):
        self.layout = layout or CycleLayout.from_describe(describe["cycle_layout"])
        self.joints = self.layout.owners()
        # each command interface's range (its bar's ends), as describe declares it
        self.ranges = {(c["joint"], c["name"]): (c["low"], c["high"]) for c in describe.get("command_interfaces", [])}
        self.state: dict | None = None  # the last row of the last state message, by field name
        self.foreign = 0  # state messages of another layout, not read
        self.stats: dict | None = None
        self.status: dict = {}
        self.events: deque[str] = deque(maxlen=5)
        self.recordings: dict[str, str] = {}  # the daemon's recordings in progress: name -> who
        self.lost = 0

    def again(self, describe: dict) -> "View":
        """This view under the layout ``describe`` now gives (what it showed kept, but the state)."""
        view = View(describe)
        view.status, view.events, view.recordings, view.stats, view.lost = (
            self.status, self.events, self.recordings, self.stats, self.lost)
        return view

    def take(self, topic: str, m: dict) -> None:
        if topic == "state":
            if fields.check(m, self.layout):
                self.state = fields.latest(m, self.layout)
            else:
                self.foreign += 1
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

    def _joint_rows(self, joint: str, row: dict, safe: bool) -> list[list]:
        """The joint's table rows: its position, set-point and error, then one command a row."""
        layout = self.layout
        pos, sp, err = (layout[f"{joint}.{q}"] for q in ("position", "setpoint", "error"))
        error = fields.display(err, row[err.name])
        commands: list[Text | str] = []
        for f in layout.of_joint(joint, "command"):
            if safe:
                commands = [Text("safe state", style="bold red")]
                break
            command = f.quantity[2:]
            commands.append(Text(f"{command} {fields.shown(f, row[f.name])} ").append_text(
                _bar(row[f.name], *self.ranges.get((joint, command), (0.0, 0.0)))))
        first = [joint, fields.shown(pos, row[pos.name]), fields.shown(sp, row[sp.name]),
                 Text("-", style="dim") if safe else Text(fields.shown(err, row[err.name]),
                                                          style="red" if abs(error) > LARGE_ERROR else "")]
        commands = commands or [""]
        return [first + [commands[0]]] + [["", "", "", "", c] for c in commands[1:]]

    def _further(self, joint: str, row: dict) -> Text | None:
        """The joint's further values, measured and commanded, each by its own name (None: none)."""
        further = [f for f in self.layout.fields if f.owner == joint and (
            f.group == "commanded" or f.group == "measured" and f.quantity not in ("position", "velocity"))]
        if not further:
            return None
        return Text(f"{joint}: " + "  ".join(f"{f.quantity} {fields.shown(f, row[f.name])}" for f in further))

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
        for name in ("joint", "position", "set-point", "error", "commands"):
            table.add_column(name, justify="right" if name in ("position", "set-point", "error") else "left",
                             no_wrap=True)
        written = Text("outputs written: waiting for telemetry", style="dim")
        rig = Text("")
        further: list[Text] = []
        if self.state is not None:
            row = self.state
            safe = row["mode"] != "enabled"  # the safe state is written, whatever the controller last said
            for joint in self.joints:
                for cells in self._joint_rows(joint, row, safe):
                    table.add_row(*cells)
            further = [t for t in (self._further(joint, row) for joint in self.joints) if t is not None]
            written = Text("outputs written: " + "  ".join(f"{f.quantity[len('out.'):]} {row[f.name]:.2f} V"
                                                            for f in self.layout.of_group("output"))
                           + ("  (safe state)" if safe else ""))
            own = [f for f in self.layout.of_group("measured") if not f.owner]
            rig = Text("rig: " + "  ".join(f"{f.name} {fields.shown(f, row[f.name])}" for f in own) if own else "")
        if self.foreign:
            rig.append(f"  ({self.foreign} state messages of another layout not shown)", style="red")
        health = Text("loop: waiting for stats", style="dim")
        if self.stats is not None:
            st = self.stats
            health = Text(f"loop: wake-up p99 {st['latency_us']['p99']:.0f} us, compute p99 "
                          f"{st['compute_us']['total']['p99']:.0f} us, overruns {st['overruns']} in the last "
                          f"{st['cycles']} cycles ({st['overruns_total']} in all); telemetry lost here {self.lost}")
        timing = _timing(s.get("timing"))
        faults = Text("faults: " + (", ".join(s.get("faults") or []) or "none"),
                      style="red" if s.get("faults") else "dim")
        recording = Text("recording: " + (", ".join(f"{name} ({who})" for name, who in self.recordings.items())
                                          or "none"), style="bold magenta" if self.recordings else "dim")
        events = Text("\n".join(self.events) or "no events yet", style="dim")
        return Panel(Group(head, table, *further, *([rig] if rig.plain else []), written, health, timing, faults, recording, Text("events:", style="bold"), events),
                     title="pneumad", subtitle="Ctrl-C to leave")


def _timing(verdict: dict | None) -> Text:
    """The messenger's last verdict on the loop's timing (``status.timing``): degraded in red with
    its cause (runs meanwhile are not valid at the loop's rate), else the rate it achieved."""
    if not verdict or verdict.get("judged_t") is None:
        return Text("timing: not judged yet", style="dim")
    if verdict.get("degraded"):
        return Text(f"timing: DEGRADED ({', '.join(verdict.get('reasons') or [])}): {verdict.get('cause', '')}",
                    style="bold red")
    return Text(f"timing: within the rig file's limits ({verdict['rate_hz']:.0f} Hz of {verdict['expected_hz']:.0f}, "
                f"{verdict['overruns']} of {verdict['deadlines']} deadlines missed over {verdict['window_s']:.0f} s)",
                style="dim")


def _holder(status: dict) -> str:
    if not status.get("lease_held"):
        return "nobody"
    return status.get("lease_holder") or "held"


def _bar(u: float, lo: float, hi: float) -> Text:
    """A command on its range, zero marked (or its low end, for a range above zero): full at
    either limit; none for a missing value or range."""
    span = hi - lo
    if span <= 0 or u != u:
        return Text("")
    zero = round(min(max(-lo / span, 0.0), 1.0) * BAR)
    at = min(max(round((u - lo) / span * BAR), 0), BAR)
    cells = [" "] * (BAR + 1)
    for i in range(min(zero, at), max(zero, at) + 1):
        cells[i] = "█"
    cells[zero] = "|"
    style = "red" if u <= lo or u >= hi else "green"
    return Text("[" + "".join(cells) + "]", style=style)
