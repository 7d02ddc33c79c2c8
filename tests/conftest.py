"""A session-wide guard: the suite is safe to run on a lab PC where ``pneumad.service`` runs;
the long tests scheduled first; and the fast subset (``-m 'not slow'``) spared the import of
files that are slow as a whole.

Once per session (in the controlling process under pytest-xdist, never in its workers):

- listeners on 127.0.0.1:5560-5562, the default endpoints a lab's daemon holds, bound at the
  start and checked at the end: any connection or byte to them fails the session, naming the
  port. A port that cannot be bound (a real daemon holds it) is not watched, and the summary
  says so; no test may reach it either way.
- the checkout's ``git status --porcelain --ignored`` taken at the start and compared at the
  end: a test that wrote, moved or deleted anything in the checkout fails the session (Python's
  and pytest's own caches excepted). Skipped outside a git checkout.
"""
from __future__ import annotations

import re
import selectors
import socket
import subprocess
import threading
from collections import defaultdict
from pathlib import Path

import pytest

from tests import extras

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_PORTS = (5560, 5561, 5562)
CACHES = ("__pycache__", ".pytest_cache")


class PortWatch:
    """Listeners on the default ports, counting every connection and byte they receive."""

    def __init__(self, ports=DEFAULT_PORTS):
        self.received: dict[int, list[str]] = {}
        self.unwatched: dict[int, str] = {}
        self.watched: list[int] = []
        self._selector = selectors.DefaultSelector()
        self._stop = threading.Event()
        for port in ports:
            listener = socket.socket()
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # still refused while another listens
            try:
                listener.bind(("127.0.0.1", port))
                listener.listen()
            except OSError as exc:
                listener.close()
                self.unwatched[port] = exc.strerror or str(exc)
                continue
            listener.setblocking(False)
            self.watched.append(port)
            self._selector.register(listener, selectors.EVENT_READ, (port, None))
        self._thread = threading.Thread(target=self._serve, name="default-port-watch", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            for key, _ in self._selector.select(timeout=0.1):
                port, peer = key.data
                if peer is None:  # a listener: someone connected
                    conn, address = key.fileobj.accept()
                    conn.setblocking(False)
                    self.received.setdefault(port, []).append(f"a connection from {address[0]}:{address[1]}")
                    self._selector.register(conn, selectors.EVENT_READ, (port, address))
                    continue
                try:
                    data = key.fileobj.recv(65536)
                except OSError:
                    data = b""
                if data:
                    self.received[port].append(f"{len(data)} bytes ({data[:16]!r}...)")
                else:
                    self._selector.unregister(key.fileobj)
                    key.fileobj.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        for key in list(self._selector.get_map().values()):
            key.fileobj.close()
        self._selector.close()


def checkout_state() -> list[str] | None:
    """``git status --porcelain --ignored`` of the checkout, caches left out; None outside git."""
    try:
        done = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--ignored"], capture_output=True,
                              text=True, timeout=60)
    except OSError:
        return None
    if done.returncode != 0:
        return None
    return sorted(line for line in done.stdout.splitlines() if not any(part in CACHES for part in Path(line[3:]).parts))


def is_controller(config) -> bool:
    """True in a plain run and in xdist's controlling process; False in its workers."""
    return not hasattr(config, "workerinput")


@pytest.hookimpl(tryfirst=True)
def pytest_sessionstart(session):
    if not is_controller(session.config):
        return
    session.config.stash[GUARD] = (PortWatch(), checkout_state())


@pytest.hookimpl(tryfirst=True)
def pytest_sessionfinish(session):
    guard = session.config.stash.get(GUARD, None)
    if guard is None:
        return
    watch, before = guard
    watch.close()
    problems = [f"127.0.0.1:{port} (a default endpoint) received {', '.join(what)}"
                for port, what in sorted(watch.received.items())]
    after = checkout_state() if before is not None else None
    if before is not None and after != before:
        gone, new = sorted(set(before) - set(after)), sorted(set(after) - set(before))
        problems.append(f"the checkout changed during the tests: before only {gone}, after only {new}")
    notes = [f"default endpoints watched: {', '.join(map(str, watch.watched)) or 'none'}"]
    notes += [f"127.0.0.1:{port} not watched (cannot bind: {why}; a daemon holds it?)"
              for port, why in sorted(watch.unwatched.items())]
    notes.append("checkout unchanged" if before is not None and after == before else
                 "checkout not checked (not a git checkout)" if before is None else "checkout CHANGED")
    session.config.stash[REPORT] = (notes, problems)
    if problems and session.exitstatus == pytest.ExitCode.OK:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


WHOLE_FILE_SLOW = re.compile(r"pytestmark = \[?pytest\.mark\.slow\b")


def pytest_ignore_collect(collection_path, config):
    """Under ``-m 'not slow'``, a test file marked slow as a whole (a line ``pytestmark =
    pytest.mark.slow...``, or a list starting with it) is not imported: every test in it would be deselected, and importing
    test_bluesky.py alone (Bluesky, ophyd-async, Tiled) costs each xdist worker 5 s. None
    otherwise: pytest decides."""
    if " ".join(config.option.markexpr.split()) != "not slow" or collection_path.suffix != ".py":
        return None
    if not collection_path.name.startswith("test_"):
        return None
    lines = collection_path.read_text().splitlines()
    return any(WHOLE_FILE_SLOW.match(line) for line in lines) or None


def pytest_collection_modifyitems(items):
    """A test marked with an extra's name (``bluesky``) is skipped, saying how to install it,
    where that extra is not installed (tests/extras.py).

    Whole files go to xdist's workers (``--dist loadfile``), the longest first and in this
    order (``--no-loadscope-reorder``; xdist's own order is by number of tests): a long file
    started last would finish alone while the other workers idle. A file's length is the sum
    of its tests': the wall time a long test states in ``slow(seconds=...)`` (measured on a
    2-core machine), 1 s for another slow test, nothing for the rest."""
    def length(item) -> float:
        mark = item.get_closest_marker("slow")
        return 0.0 if mark is None else float(mark.kwargs.get("seconds", 1.0))

    for extra in extras.EXTRAS:
        if extras.missing(extra):
            for item in items:
                if item.get_closest_marker(extra):
                    item.add_marker(pytest.mark.skip(reason=extras.reason(extra)))
    per_file: dict = defaultdict(float)
    for item in items:
        per_file[item.path] += length(item)
    first_seen = {path: i for i, path in enumerate(dict.fromkeys(item.path for item in items))}
    items.sort(key=lambda item: (-per_file[item.path], first_seen[item.path]))


def pytest_terminal_summary(terminalreporter, config):
    notes, problems = config.stash.get(REPORT, ([], []))
    if notes or problems:
        terminalreporter.section("lab-PC guard")
    for line in notes:
        terminalreporter.write_line(line)
    for line in problems:
        terminalreporter.write_line("FAILED: " + line, red=True)


GUARD = pytest.StashKey[tuple]()
REPORT = pytest.StashKey[tuple]()
