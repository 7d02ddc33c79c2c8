"""Work done off the loop: building a controller or deriving its parameters (a Riccati solve,
a c2d) takes milliseconds, several cycles, so it runs in a separate worker process and the
loop only swaps the result in at a cycle boundary.

A thread beside the loop was measured first (docs/benchmarks.md, "switch load"): it holds
the GIL for milliseconds at a time and costs the loop an overrun per build. The process
holds no lock the loop needs. What stays in the daemon is one courier thread that sends a
job, waits for the answer and pickles/unpickles them (tens of microseconds per job); the loop
thread only puts a job on a queue and later reads a finished future.

The courier is created with the daemon, before the real-time set-up, so it and every worker
it spawns keep the normal scheduling policy; the worker is a helper process
(:class:`hal.process.Helper`: a fresh interpreter, never a fork of the loop's process), which
drops any real-time policy it might have inherited, runs its builds at nice 10 and dies with
the daemon (the warm-up at the daemon's start, before the loop runs, at the normal priority:
at nice 19 beside two busy processes its imports took longer than the job limit and the
daemon did not start). Nice 10, not 19: a waking nice-0 courier or --no-rt loop still takes
the CPU from it at once and outweighs it 9 to 1, while beside two CPU hogs a 0.6 s build
(the largest input multisine's) took 15-40 s at nice 19, and over 600 s in a loaded test run. It is started on the first job or by :meth:`Preparer.warm`.
The courier watches it while it waits for a job: a worker that dies, idle or on a job (which
fails that job alone), or overruns its time limit is replaced at once and warmed (the
warm-up's imports at the normal priority), so the next request neither pays for the new
worker nor is refused; each replacement is a notice the loop takes (:meth:`Preparer.check`)
and publishes as a ``planner`` event. One job at a time: a second request while one is
prepared is refused, so a flood of expensive requests cannot queue up work.
"""
from __future__ import annotations

import os
import queue
import signal
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait

from hal.process import Child, Helper, HelperFailed

DEFAULT_TIME_LIMIT_S = 30.0  # a build slower than this is taken as hung and its worker stopped
REAP_S = 1.0  # a worker whose socket closed is waited for this long to be reaped before it is killed [s]
BUILD_NICE = 10  # the worker's priority for every job but the warm-up


class PreparationFailed(RuntimeError):
    """The worker died or overran its time limit; the job was not done and nothing applied."""


@dataclass
class Deferred:
    """A command whose reply waits for work off the loop. ``finish(result)`` runs on the loop
    thread once the work is done, applies it at that cycle boundary and returns the reply."""

    future: Future
    finish: Callable[[object], dict]
    request_id: object = None  # of the request it answers, set by the command layer
    client: object = None  # who sent it (a daemon.wire.keys.Identity), set by the command layer


class Preparer:
    """Runs ``function(*args)`` in a worker process, one job at a time. ``function`` and its
    arguments must pickle (module-level functions, plain data, controller classes)."""

    def __init__(self, time_limit_s: float = DEFAULT_TIME_LIMIT_S):
        self.time_limit_s = time_limit_s
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._wake, self._woken = socket.socketpair()  # a byte with every job: the courier waits on it and on the worker
        self._wake.setblocking(False)
        self._current: Future | None = None
        self._cpus = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
        self._worker: _Worker | None = None
        self.restarts = 0
        self.last_exit_code: int | None = None
        self._notices: deque[str] = deque()  # the courier's news of replaced workers, for the loop's events
        # plugin files' versions (controllers.directory.Source) sent ahead of every job, so a
        # worker, a new one too, has each module a job's classes come from; set by the loop's thread
        self.sources: tuple = ()
        self._courier = threading.Thread(target=self._carry, name="pneumad-prepare", daemon=True)
        self._courier.start()

    @property
    def busy(self) -> bool:
        return self._current is not None and not self._current.done()

    def warm(self) -> Future:
        """Spawn the worker and import the controllers now, so the first switch is quick."""
        return self._put(_warm, ())

    def submit(self, finish: Callable[[object], dict], function: Callable, *args) -> Deferred:
        """Start ``function(*args)`` in the worker; the caller checks :attr:`busy` first."""
        self._current = self._put(function, args)
        return Deferred(self._current, finish)

    def check(self) -> str | None:
        """The loop's look (never waiting): a worker replaced since the last look, said as an
        event's cause; None if none was."""
        try:
            return self._notices.popleft()
        except IndexError:
            return None

    def health(self) -> dict:
        """The worker as the courier last left it (the status field ``helpers``)."""
        worker = self._worker
        return {"running": worker is not None and worker.warm, "pid": worker.pid if worker is not None else None,
                "restarts": self.restarts, "last_exit_code": self.last_exit_code}

    def close(self) -> None:
        self._jobs.put(None)
        self._ring()

    def _put(self, function: Callable, args: tuple) -> Future:
        future: Future = Future()
        self._jobs.put((future, function, args))
        self._ring()
        return future

    def _ring(self) -> None:
        try:
            self._wake.send(b"\0")
        except OSError:
            pass  # full: the courier has plenty of bytes to wake it (or closed: it has ended)

    # -- the courier thread -------------------------------------------------------------
    def _carry(self) -> None:
        try:
            while (job := self._next_job()) is not None:
                future, function, args = job
                if future.set_running_or_notify_cancel():
                    self._run(future, function, args)
        finally:
            if self._worker is not None:
                self._worker.stop()
            self._woken.close()
            self._wake.close()

    def _next_job(self):
        """The next job (None: closed), waited for; a worker that ends meanwhile is replaced."""
        while True:
            try:
                return self._jobs.get_nowait()
            except queue.Empty:
                pass
            watched = [self._woken] if self._worker is None else [self._woken, self._worker.conn]
            ready = wait(watched)
            if self._woken in ready:
                self._woken.recv(4096)
            if self._worker is not None and self._worker.conn in ready:  # idle, it never speaks: it ended
                self._replace("the planner worker died while idle", dead=True)

    def _run(self, future: Future, function: Callable, args: tuple) -> None:
        try:
            if self._worker is None:
                self._worker = _Worker(self._cpus, self.time_limit_s)
            ok, value = self._worker.call(function, args, self.time_limit_s, self.sources)
        except PreparationFailed as exc:
            future.set_exception(exc)  # the request's refusal first; then the replacement
            if self._worker is not None:
                overran = self._worker.overran
                self._replace(f"the planner worker {'was stopped' if overran else 'died on a job'}: {exc}",
                              dead=not overran)
            return
        except Exception as exc:  # the job itself would not pickle: refused, the worker is fine
            future.set_exception(exc)
            return
        if ok:
            self._worker.warm = self._worker.warm or function is _warm  # before the result: whoever waited sees it warm
            future.set_result(value)
        else:
            future.set_exception(value)

    def _replace(self, cause: str, dead: bool) -> None:
        """Stop the worker (``dead``: it ended by itself, or by a signal from outside) and start
        another, warmed, at once (the next job waits for it). The cause says whether the
        daemon's own SIGKILL ended it, so an outside kill is never taken for a stop of ours."""
        code, ours = self._worker.ended(dead)
        self._worker = None
        self.restarts += 1
        self.last_exit_code = code
        cause = f"{cause} ({_how_it_ended(code, ours)})"
        try:
            self._worker = _Worker(self._cpus, self.time_limit_s)
            ok, value = self._worker.call(_warm, (), self.time_limit_s, self.sources)
            if not ok:
                raise PreparationFailed(f"its warm-up failed: {value}")
            self._worker.warm = True
            self._notices.append(f"{cause}; another was started and warmed (restart {self.restarts})")
        except PreparationFailed as exc:
            if self._worker is not None:
                self._worker.stop()
            self._worker = None
            self._notices.append(f"{cause}; another could not be started ({exc}): the next request starts one")


class _Worker:
    """One helper process at the end of a socket pair."""

    def __init__(self, cpus, start_limit_s: float):
        ours, theirs = socket.socketpair()
        self.conn = Connection(ours.detach())
        self.warm = False  # its warm-up done
        self.overran = False  # a job of its outlasted its time limit: the daemon stops it
        self._process = Helper("daemon.planner.process:serve", (theirs.fileno(),), name="the preparation worker",
                               pass_fds=(theirs.fileno(),), nice=0, cpus=cpus)
        try:
            self._process.start(start_limit_s)
        except HelperFailed as exc:
            self.conn.close()
            raise PreparationFailed(f"{exc}; nothing was applied") from None
        finally:
            theirs.close()

    @property
    def pid(self) -> int | None:
        return self._process.pid

    def call(self, function: Callable, args: tuple, time_limit_s: float, sources: tuple = ()) -> tuple[bool, object]:
        """(True, result) or (False, the exception the job raised); PreparationFailed if
        the worker died or did not answer in time. ``sources`` arrive first (executed there)."""
        started = time.monotonic()
        try:
            self.conn.send((sources, function, args))  # (a job that will not pickle raises here, not as EOF or OSError)
            if not self.conn.poll(time_limit_s):
                self.overran = True
                raise PreparationFailed(f"the preparation took longer than {time_limit_s:g} s and was stopped; "
                                        f"nothing was applied (a PC busy with other work: pneumad run "
                                        f"--prepare-limit-s)")
            return self.conn.recv()
        except (EOFError, OSError):
            code = self._process.join(1.0)
            raise PreparationFailed(f"the preparation worker died (exit code {code}) "
                                    f"after {time.monotonic() - started:.1f} s; nothing was applied; "
                                    f"a new worker takes the next request") from None

    def ended(self, dead: bool) -> tuple[int | None, bool]:
        """Make sure it has ended: one that is ``dead`` (its socket closed) is given up to
        ``REAP_S`` to be reaped, then any still alive gets SIGKILL. Its exit code, and whether
        the daemon's SIGKILL ended it."""
        deadline = time.monotonic() + (REAP_S if dead else 0.0)
        while self._process.alive and time.monotonic() < deadline:
            time.sleep(0.01)
        ours = self._process.alive
        code = self._process.kill()
        self.conn.close()
        return code, ours

    def stop(self) -> None:
        self._process.kill()
        self.conn.close()


def _how_it_ended(code: int | None, ours: bool) -> str:
    """A worker's end in words: the daemon's SIGKILL, another's signal, or its own exit."""
    if ours:
        return f"stopped by the daemon with SIGKILL, exit code {code}"
    if code is not None and code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"exit code {code}: {name} from outside the daemon"
    return f"exit code {code}"


# -- in the worker process ----------------------------------------------------------------
def serve(child: Child, fd: int) -> None:
    """The worker's main: answer jobs until the socket closes. Every job but the warm-up at
    BUILD_NICE, so the courier, which holds the GIL while it unpickles, is never waiting for a
    CPU behind the worker (the loop would wait for the courier)."""
    conn = Connection(fd)
    child.ready()
    while True:
        try:
            _sources, function, args = conn.recv()  # the sources, unpickled first, execute their modules
        except (EOFError, OSError):
            return
        except Exception as exc:  # a job that cannot arrive here (a plugin's module fails here): refused alone
            conn.send((False, PreparationFailed(f"the job could not be read in the worker: {type(exc).__name__}: "
                                                f"{exc}")))
            continue
        if function is not _warm and os.getpriority(os.PRIO_PROCESS, 0) < BUILD_NICE:
            os.setpriority(os.PRIO_PROCESS, 0, BUILD_NICE)
        try:
            reply = (True, function(*args))
        except Exception as exc:
            reply = (False, exc)
        try:
            conn.send(reply)
        except Exception as exc:  # a result or exception that will not pickle
            conn.send((False, PreparationFailed(f"the result could not be sent back from the worker: "
                                                f"{type(exc).__name__}: {exc}")))


def _warm() -> None:
    """Import every built-in controller (and numpy, scipy with them), and scipy.signal, which
    they import only where they build."""
    import scipy.signal  # noqa: F401

    from controllers import registry
    for name in registry.available():
        try:
            registry.load(name)
        except LookupError:
            pass  # a broken plugin is reported when someone asks for it
