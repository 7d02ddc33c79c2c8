"""One handle for every process beside the loop: the messenger, the recorder, the planner's
worker, the contact sensor's process and the off-loop transports' exchange.

A helper is a fresh interpreter (``python -m hal.process MODULE:FUNCTION``: never a fork of
the loop's process, which holds threads and locked memory), so its command line names what
it runs. The parent hands it, on its stdin, its own ``sys.path`` (a job's function from any
importable module unpickles there) and the function's pickled arguments; file descriptors
it must share (a doorbell pipe, :class:`SharedMemory`, a socket) are kept at the same number.

Before the function runs the child is set up the one way every helper needs:
- it dies with its parent (Linux's PR_SET_PDEATHSIG: SIGKILL, or SIGTERM for one that must
  finish its files), and :meth:`Child.parent_alive` covers other systems, one check later;
- it ignores SIGINT and SIGTERM unless told otherwise (Ctrl-C and ``systemctl stop`` reach the
  whole process group; the daemon decides when its helpers end);
- with ``nice`` given, it leaves any real-time policy it inherited for the normal one at that
  nice, on ``cpus`` (the CPUs the daemon had before its real-time set-up).
Then ``function(child, *args)`` runs; it calls :meth:`Child.ready` (with a payload, such as
the endpoints it bound) once it serves, or raises :class:`HelperFailed` in its own words.
The parent's :meth:`Helper.start` waits for that within a limit and raises
:class:`HelperFailed` saying which happened: refused, exited, or silent.

A helper whose restart must be quick (the messenger: clients wait on it) keeps a *spare*
(``Helper(..., spare=True)``): a second child started ahead, which runs its function up to
:meth:`Child.standby` (the interpreter started, the imports done, nothing of its
predecessor's taken yet: no socket bound) and waits there on its stdin. When the running
child dies the spare is put in service (one byte on that pipe: nothing in the parent
waits) and the next spare is started once it is ready.
"""
from __future__ import annotations

import copy
import ctypes
import importlib
import mmap
import os
import pickle
import signal
import subprocess
import sys
from collections.abc import Iterable
from multiprocessing.connection import Connection

READY_LIMIT_S = 30.0  # a helper that has not said it is ready by then is taken as hung [s]
_PR_SET_PDEATHSIG = 1


class HelperFailed(RuntimeError):
    """A helper did not start: what it said, or that it exited or stayed silent."""


class Helper:
    """The parent's handle on one helper process: start it (and wait for it to be ready),
    see whether it lives, start it again, stop it.

    ``target`` is ``"module:function"``; ``args`` must pickle. ``pass_fds``: descriptors the
    child keeps at the same numbers. ``death_signal``: what the child gets when its parent
    dies. ``ignore``: signals the child ignores. ``nice``/``cpus``: see the module. ``spare``:
    keep a spare child waiting at :meth:`Child.standby`, put in service when this one dies."""

    def __init__(self, target: str, args: tuple = (), *, name: str | None = None, pass_fds: Iterable[int] = (),
                 death_signal: int = signal.SIGKILL, ignore: Iterable[int] = (signal.SIGINT, signal.SIGTERM),
                 nice: int | None = None, cpus: Iterable[int] | None = None, spare: bool = False):
        self.target, self.args = target, tuple(args)
        self.name = name or target.partition(":")[0]
        self.pass_fds = tuple(pass_fds)
        self._setup = {"death_signal": int(death_signal), "ignore": [int(s) for s in ignore], "nice": nice,
                       "cpus": sorted(cpus) if cpus is not None else None}
        self.restarts = 0
        self.last_exit_code: int | None = None  # the last child's that died
        self.keeps_spare = spare
        self._spare: Helper | None = None  # a child waiting at Child.standby
        self._proc: subprocess.Popen | None = None
        self._ready: Connection | None = None
        self.payload = None  # what the child said with ready()
        self.is_ready = False

    # -- starting ---------------------------------------------------------------------------
    def spawn(self, standby: bool = False) -> None:
        """Start the child and return at once (:meth:`poll_ready` or :meth:`wait_ready` follow);
        ``standby``: one that waits at :meth:`Child.standby` until :meth:`_put_in_service`."""
        args = pickle.dumps(self.args)  # one that will not pickle fails here, before any child
        read, write = os.pipe()
        header = {"sys_path": list(sys.path), "parent": os.getpid(), "ready_fd": write, "standby": standby,
                  **self._setup}
        self._ready = Connection(read, writable=False)
        try:  # the interpreter's own flags (-B, -X ...) as multiprocessing passes them on
            self._proc = subprocess.Popen([sys.executable, *subprocess._args_from_interpreter_flags(), "-m", "hal.process",
                                           self.target], stdin=subprocess.PIPE, pass_fds=(write, *self.pass_fds))
        except OSError:
            self._close_ready()
            raise
        finally:
            os.close(write)
        self.is_ready, self.payload = False, None
        try:
            pickle.dump(header, self._proc.stdin)
            self._proc.stdin.write(args)
            if standby:
                self._proc.stdin.flush()  # kept open: the byte that puts it in service comes later
            else:
                self._proc.stdin.close()
        except BrokenPipeError:
            pass  # it died at once: wait_ready says so

    def start(self, limit_s: float = READY_LIMIT_S):
        """Spawn the child and wait until it is ready; its payload. HelperFailed (the child
        stopped) if it refused, exited or stayed silent for ``limit_s``."""
        self.spawn()
        return self.wait_ready(limit_s)

    def wait_ready(self, limit_s: float = READY_LIMIT_S):
        if not self._poll_ready(limit_s):
            self.kill()
            raise HelperFailed(f"{self.name}: not ready within {limit_s:g} s of starting")
        return self.payload

    def poll_ready(self) -> bool:
        """Whether the child has said it is ready (never waits); HelperFailed if it refused."""
        return self._poll_ready(0.0)

    def _poll_ready(self, limit_s: float) -> bool:
        if self.is_ready:
            return True
        if not self._ready.poll(limit_s):
            return False
        reap_s = 5.0 if limit_s else 0.0  # poll_ready never waits
        try:
            kind, said = self._ready.recv()
        except (EOFError, OSError):
            code = self._wait(reap_s)
            raise HelperFailed(f"{self.name}: exited (code {code}) before it was ready") from None
        if kind != "ready":
            self._wait(reap_s)
            raise HelperFailed(said)
        self.is_ready, self.payload = True, said
        return True

    # -- watching -----------------------------------------------------------------------------
    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    def exitcode(self) -> int | None:
        """The child's exit code (negative: the signal that ended it); None while it runs."""
        return self._proc.poll() if self._proc is not None else None

    def restart_if_dead(self) -> int | None:
        """Never waits: if the child has ended, start another (the spare, if one waits, else a
        new one; not waiting for it to be ready) and return the old one's exit code; None if
        it lives. With ``spare``, a living child that has said it is ready gets its spare
        started here, if it has none."""
        code = self.exitcode()
        if code is None:
            if self.keeps_spare and self._spare is None and self.is_ready:
                self._spare = copy.copy(self)
                self._spare.keeps_spare, self._spare._spare = False, None
                self._spare.spawn(standby=True)
            return None
        self._close_ready()
        self.restarts += 1
        self.last_exit_code = code
        if not self._put_in_service():
            self.spawn()
        return code

    def _put_in_service(self) -> bool:
        """The spare takes the dead child's place (one byte on its stdin: it goes on past
        Child.standby); False if there is none alive."""
        spare, self._spare = self._spare, None
        if spare is None:
            return False
        try:
            if not spare.alive:
                raise BrokenPipeError
            spare._proc.stdin.write(b"g")
            spare._proc.stdin.close()
        except (OSError, ValueError):  # it died while it waited
            spare.kill()
            spare._close_ready()
            return False
        self._proc, self._ready, self.is_ready, self.payload = spare._proc, spare._ready, False, None
        return True

    def health(self) -> dict:
        """As of the last look (:meth:`restart_if_dead`, :meth:`poll_ready`): whether the child
        serves (alive and said ready) and its pid, how often it was restarted, the last dead
        one's exit code."""
        return {"running": self.is_ready, "pid": self.pid if self.is_ready else None, "restarts": self.restarts,
                "last_exit_code": self.last_exit_code}

    def send_signal(self, sig: int) -> None:
        if self.alive:
            self._proc.send_signal(sig)

    # -- stopping -----------------------------------------------------------------------------
    def join(self, timeout: float = 2.0, terminate_first: bool = False) -> int | None:
        """Wait ``timeout`` for the child to end by itself (once told to, its own way); then
        SIGTERM and as long again (with ``terminate_first``), then SIGKILL. Its exit code."""
        if self._proc is None:
            return None
        self._dismiss_spare()
        code = self._wait(timeout)
        if code is None and terminate_first:
            self._proc.terminate()
            code = self._wait(timeout)
        if code is None:
            code = self.kill()
        self._close_ready()
        return code

    def kill(self) -> int | None:
        """SIGKILL and reap (the spare too); the exit code."""
        self._dismiss_spare()
        if self._proc is None:
            return None
        if self._proc.poll() is None:
            self._proc.kill()
        return self._proc.wait()

    def _dismiss_spare(self) -> None:
        spare, self._spare = self._spare, None
        if spare is not None:
            spare.kill()
            spare._close_ready()

    def _wait(self, timeout: float) -> int | None:
        try:
            return self._proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return None

    def _close_ready(self) -> None:
        if self._ready is not None:
            self._ready.close()
            self._ready = None


class SharedMemory:
    """Numbers a parent shares with its helper (a seqlock's counter and values, flags,
    counters), laid out in one anonymous memory file that the helper maps by its descriptor
    (hand :attr:`fd` in ``pass_fds``). ``fields``: name -> ctypes type (``c_uint64``,
    ``c_double * 20``...); each attribute is a ctypes object with ``.value`` or slices."""

    def __init__(self, fields: dict[str, type], _fd: int | None = None):
        self._fields = dict(fields)
        offsets, size = {}, 0
        for name, ctype in self._fields.items():
            offsets[name] = size
            size += -(-ctypes.sizeof(ctype) // 8) * 8  # each field 8-byte aligned
        if _fd is None:
            _fd = os.memfd_create("pneumad-shared")
            os.ftruncate(_fd, size)
        self.fd = _fd
        self._map = mmap.mmap(_fd, size)
        for name, ctype in self._fields.items():
            setattr(self, name, ctype.from_buffer(self._map, offsets[name]))

    def __reduce__(self):  # the child holds the same descriptor number; array types pickle as (item, length)
        spec = {name: (t._type_, t._length_) if issubclass(t, ctypes.Array) else (t, 0) for name, t in self._fields.items()}
        return _attach, (spec, self.fd)


def _attach(spec: dict[str, tuple[type, int]], fd: int) -> SharedMemory:
    return SharedMemory({name: item * length if length else item for name, (item, length) in spec.items()}, fd)


# -- in the helper process ---------------------------------------------------------------------
class Child:
    """What a helper's function is given: say it is ready, ask whether its parent lives, wait
    as a spare."""

    def __init__(self, ready_fd: int, parent: int, go=None):
        self._ready = Connection(ready_fd, readable=False)
        self._parent = parent
        self._go = go  # a spare's stdin, on which the byte that puts it in service comes
        self.said = False

    def standby(self) -> None:
        """Where a spare waits (its imports done, nothing of its predecessor's taken yet)
        until it is put in service; at once in a child started the ordinary way. A spare
        dismissed, or whose parent is gone, ends here."""
        go, self._go = self._go, None
        if go is None:
            return
        word = go.read(1)
        go.close()
        if word != b"g":
            self.said = True  # nobody listens for a dismissed spare
            raise SystemExit(0)

    def ready(self, payload=None) -> None:
        self._say("ready", payload)

    def fail(self, message: str) -> None:
        self._say("failed", message)

    def parent_alive(self) -> bool:
        return os.getppid() == self._parent

    def _say(self, kind: str, payload) -> None:
        if not self.said:
            self.said = True
            try:
                self._ready.send((kind, payload))
            except OSError:
                pass  # the parent is gone or stopped listening
            self._ready.close()


def die_with_parent(sig: int = signal.SIGKILL) -> None:
    """Ask Linux to send ``sig`` to this process when its parent (the thread that started
    it) ends (prctl PR_SET_PDEATHSIG); elsewhere a no-op, :meth:`Child.parent_alive` covers it."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, sig)
    except (OSError, AttributeError):
        pass


def place(nice: int | None, cpus) -> None:
    """The normal scheduling class at ``nice``, on ``cpus``, whatever this process inherited
    from the loop (a helper must never compete with it). Best effort: a helper that cannot
    change these still works."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        if nice:
            os.setpriority(os.PRIO_PROCESS, 0, nice)
        if cpus:
            os.sched_setaffinity(0, cpus)
    except (AttributeError, OSError):
        pass


def _child_main(target: str) -> int:
    stdin = sys.stdin.buffer
    header = pickle.load(stdin)
    sys.path[:] = header["sys_path"]
    for sig in header["ignore"]:
        signal.signal(sig, signal.SIG_IGN)
    die_with_parent(header["death_signal"])
    child = Child(header["ready_fd"], header["parent"], stdin if header["standby"] else None)
    if not child.parent_alive():
        return 1  # the parent died before the death signal was armed
    if header["nice"] is not None:
        place(header["nice"], header["cpus"])
    try:
        module, _, name = target.partition(":")
        function = getattr(importlib.import_module(module), name)
        args = pickle.load(stdin)
    except Exception as exc:
        child.fail(f"{target}: cannot load: {type(exc).__name__}: {exc}")
        return 1
    if not header["standby"]:
        stdin.close()
    try:
        code = function(child, *args)
    except HelperFailed as exc:
        child.fail(str(exc))
        return 1
    except BaseException as exc:
        if not child.said:
            child.fail(f"{target}: {type(exc).__name__}: {exc}")
        raise
    return code or 0


if __name__ == "__main__":  # run as the canonical module, whose HelperFailed the target raises
    from hal.process import _child_main as main
    sys.exit(main(sys.argv[1]))
