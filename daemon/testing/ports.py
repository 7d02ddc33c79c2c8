"""Loopback TCP ports for tests and benches that must run something on TCP (a Modbus peer, a
daemon bound past loopback, the README's lines): a port handed out here is given to no other
test or bench process on this machine while its process lives.

Asking the kernel for a free port (bind to port 0, then close) leaves a window in which
another process, such as a parallel test worker, is given the same port before the test's
server binds it: "Address already in use", or worse, a test that talks to another's server.
So a port is reserved by a lock file that this process holds until it ends (the kernel drops
the lock of a process that dies), and is taken from below the kernel's ephemeral range, where
neither a bind to port 0 nor an outgoing connection's source port lands."""
from __future__ import annotations

import fcntl
import os
import random
import socket
import tempfile

PORTS = range(20000, 30000)  # below Linux's ephemeral ports (32768-60999), clear of the daemon's 5560-5562
LOCKS = os.path.join(tempfile.gettempdir(), "pneumad-test-ports")
_held: list[int] = []  # the lock files' descriptors, open (so locked) for this process's life


def free_tcp_port() -> int:
    """A loopback port nobody listens on, reserved for this process."""
    os.makedirs(LOCKS, exist_ok=True)
    start = random.randrange(len(PORTS))
    for i in range(len(PORTS)):
        port = PORTS[(start + i) % len(PORTS)]
        if _reserve(port):
            return port
    raise RuntimeError(f"no free port in {PORTS.start}-{PORTS.stop - 1}")


def free_tcp_ports(n: int) -> list[int]:
    return [free_tcp_port() for _ in range(n)]


def _reserve(port: int) -> bool:
    fd = os.open(os.path.join(LOCKS, f"{port}.lock"), os.O_CREAT | os.O_RDWR, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with socket.socket() as s:  # and nothing outside the tests holds it
            s.bind(("127.0.0.1", port))
    except OSError:
        os.close(fd)
        return False
    _held.append(fd)
    return True
