"""Who holds an endpoint on this machine, as ``ss -lp`` would say: the listening TCP or Unix
socket behind a ZeroMQ ``tcp://`` or ``ipc://`` endpoint, read from /proc/net, and the
process whose descriptors hold it (only those this user may see: all of them as root).
For ``pneumactl doctor``, and for the messenger, which refuses an endpoint another program
listens on (:func:`held_by`)."""
from __future__ import annotations

import os
from dataclasses import dataclass

LISTEN = "0A"  # /proc/net/tcp's state of a listening socket
ACCEPTING = 0x10000  # /proc/net/unix's flag of a listening socket (__SO_ACCEPTCON)


@dataclass(frozen=True)
class Holder:
    """A process that holds a listening socket (``pid`` None: one this user cannot see)."""

    pid: int | None
    command: str  # its command line, or "" for one not seen

    def __str__(self) -> str:
        return f"pid {self.pid} ({self.command})" if self.pid is not None else "a process this user cannot see"


def listening_inodes(endpoint: str, proc: str = "/proc") -> list[int]:
    """The inodes of the listening sockets ``endpoint`` (``tcp://HOST:PORT``, ``ipc://PATH``)
    would bind; [] for none, or another transport."""
    scheme, _, address = endpoint.partition("://")
    if scheme == "tcp":
        port = address.rpartition(":")[2]
        if not port.isdigit():
            return []
        found = []
        for table in ("tcp", "tcp6"):
            for fields in _rows(os.path.join(proc, "net", table)):
                if len(fields) > 9 and fields[3] == LISTEN and int(fields[1].rpartition(":")[2], 16) == int(port):
                    found.append(int(fields[9]))
        return found
    if scheme == "ipc":
        path = os.path.abspath(address)
        return [int(f[6]) for f in _rows(os.path.join(proc, "net", "unix"))
                if len(f) > 7 and f[7] == path and int(f[3], 16) & ACCEPTING]
    return []


def holders(inodes: list[int], proc: str = "/proc") -> list[Holder]:
    """The processes whose descriptors hold one of the socket ``inodes``; one unseen holder when
    none of those this user may look at does."""
    if not inodes:
        return []
    wanted = {f"socket:[{inode}]" for inode in inodes}
    found = []
    for pid in (int(p) for p in os.listdir(proc) if p.isdigit()):
        fd_dir = os.path.join(proc, str(pid), "fd")
        try:
            links = {os.readlink(os.path.join(fd_dir, fd)) for fd in os.listdir(fd_dir)}
        except OSError:  # gone, or not ours to read
            continue
        if links & wanted:
            found.append(Holder(pid, command_line(pid, proc)))
    return found or [Holder(None, "")]


def command_line(pid: int, proc: str = "/proc") -> str:
    try:
        with open(os.path.join(proc, str(pid), "cmdline"), "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace").strip()
    except OSError:
        return ""


def parent_of(pid: int, proc: str = "/proc") -> int | None:
    try:
        with open(os.path.join(proc, str(pid), "stat")) as f:
            return int(f.read().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError, IndexError):
        return None


def _rows(path: str) -> list[list[str]]:
    try:
        with open(path) as f:
            return [line.split() for line in f.readlines()[1:]]
    except OSError:
        return []


def held_by(endpoint: str, proc: str = "/proc") -> str:
    """Who listens on ``endpoint`` now, in words ("": nobody). ZeroMQ binds an ``ipc://``
    endpoint by unlinking its socket file first, so a second daemon given a running one's
    endpoints would take them over without a word, the first's loop left unreachable; the
    kernel refuses a ``tcp://`` port itself, and this names who holds it."""
    found = holders(listening_inodes(endpoint, proc), proc)
    return ", ".join(map(str, found))

