"""Progress of a long command: a reference running on the daemon and the daemon's recording
of it, followed until both have ended (``pneumactl ... --wait``), and a recording made here
(``pneumactl record``).

In a terminal a rich progress bar (the reference's name, elapsed / total, time left, the
arm's state); piped, a line every ``LINE_EVERY_S``. It follows ``status`` on the control
socket, so it works for any client that may read, and stops early with the cause when the
arm leaves ``enabled`` (a trip, an e-stop). Ctrl-C leaves it with one line (:class:`Interrupted`):
what runs on in the daemon and the command that stops it; following is all it stops.
"""
from __future__ import annotations

import sys
import time
from contextlib import contextmanager

from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

from daemon.client.client import Client, Interrupted

POLL_S = 0.2
LINE_EVERY_S = 5.0
RECORDING_WAIT_S = 15.0  # a recording ends a few seconds after its reference (the settling)


def follow(client: Client, total_s: float, recording: str | None = None) -> dict:
    """Until the reference ends (or the arm stops being enabled), then until ``recording``
    has been written; what happened: ``{ended, state, cause, recording_file}``."""
    seen: dict = {}  # the last status polled, and when
    try:
        status = _track(client, max(total_s, 1e-3), seen)
    except KeyboardInterrupt:
        raise Interrupted(_left_running(seen, recording)) from None
    outcome = {"ended": status["state"] == "enabled", "state": status["state"], "cause": status.get("cause", "")}
    if recording:
        try:
            outcome["recording_file"] = recording_file(client, recording)
        except KeyboardInterrupt:
            raise Interrupted(f"interrupted: the reference has ended; the daemon finishes its recording {recording} "
                              f"(`pneumactl record.list` lists it)") from None
    return outcome


def _left_running(seen: dict, recording: str | None) -> str:
    """What a Ctrl-C while following leaves running, from the last status seen."""
    status = seen.get("status")
    if status is None or status["state"] != "enabled" or status["reference_remaining_s"] <= 0.0:
        return "interrupted: nothing was left running" + (
            f" (the daemon finishes its recording {recording})" if recording else "")
    left = max(status["reference_remaining_s"] - (time.monotonic() - seen["at"]), 0.0)
    recorded = f", recorded by the daemon as {recording}" if recording else ""
    return (f"interrupted: {status['reference'] or 'the reference'} runs on in the daemon (about {left:.0f} s left"
            f"{recorded}); `pneumactl abort` stops it and holds the arm where it is")


def _track(client: Client, total_s: float, seen: dict) -> dict:
    if sys.stderr.isatty():
        with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed:.1f}/{task.total:.1f} s"),
                      TimeRemainingColumn(), TextColumn("{task.fields[state]}"), transient=False) as bar:
            task = bar.add_task("reference", total=total_s, state="")
            return _poll(client, lambda name, done, state: bar.update(task, description=name, completed=done,
                                                                         state=state), seen)
    last = [0.0]

    def line(name, done, state):
        if time.monotonic() - last[0] >= LINE_EVERY_S:
            last[0] = time.monotonic()
            print(f"{name}: {done:.1f} of {total_s:.1f} s ({state})", file=sys.stderr, flush=True)
    return _poll(client, line, seen)


def _poll(client: Client, show, seen: dict) -> dict:
    start = time.monotonic()
    while True:
        status = client.call("status", control=True)
        seen.update(status=status, at=time.monotonic())
        left = status["reference_remaining_s"]
        show(status["reference"] or "hold", time.monotonic() - start, status["state"])
        if status["state"] != "enabled" or left <= 0.0:
            return status
        time.sleep(min(POLL_S, left))


def recording_file(client: Client, name: str) -> str | None:
    """The file of the daemon's recording ``name`` once it is finished (None if it never appeared,
    or stopped growing for ``RECORDING_WAIT_S`` without finishing). A recorder behind its feed (a
    loaded PC) is waited for as long as it writes, and, before the recording appears, as long as
    it takes in its feed short of the daemon's time now (a reference's recording starts when the
    recorder reaches the reference's start, which was before now). A listing not answered in the
    client's time is asked again: the recorder answers it after closing the file, late on a
    loaded PC."""
    try:
        now_t = client.status()["t"]  # the daemon's clock
    except TimeoutError:
        now_t = None
    end, written, fed = time.monotonic() + RECORDING_WAIT_S, -1, None
    while time.monotonic() < end:
        try:
            listing = client.record_list()
        except TimeoutError:
            continue
        active = [a for a in listing["active"] if a["name"] == name]
        if not active and any(f["name"] == name for f in listing["files"]):
            return f"{listing['directory']}/{name}.mcap"
        feed_t = listing.get("feed_t")
        if active and active[0]["messages"] > written:  # still writing: wait on
            written, end = active[0]["messages"], time.monotonic() + RECORDING_WAIT_S
        elif not active and now_t is not None and feed_t is not None and fed != feed_t and feed_t < now_t:
            fed, end = feed_t, time.monotonic() + RECORDING_WAIT_S  # catching up to where it starts: wait on
        time.sleep(POLL_S)
    return None


@contextmanager
def recording_bar(path: str, seconds: float):
    """A ``progress(elapsed_s, messages, lost)`` for :func:`daemon.recordings.mcap_log.record`: a bar in a
    terminal, a line every ``LINE_EVERY_S`` when piped."""
    if sys.stderr.isatty():
        with Progress(TextColumn(f"recording {path}"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
                      TextColumn("{task.fields[counts]}")) as bar:
            task = bar.add_task("record", total=seconds, counts="")
            yield lambda elapsed, messages, lost: bar.update(task, completed=elapsed,
                                                             counts=f"{messages} messages, lost {lost}")
        return
    last = [0.0]

    def line(elapsed, messages, lost):
        if elapsed - last[0] >= LINE_EVERY_S:
            last[0] = elapsed
            print(f"recording {path}: {elapsed:.0f} of {seconds:g} s, {messages} messages, lost {lost}",
                  file=sys.stderr, flush=True)
    yield line
