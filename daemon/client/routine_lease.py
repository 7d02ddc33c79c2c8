"""The lease of a client routine that runs for minutes (``pneumactl identify``, ``pneumactl
payload identify``): taken, renewed from a thread, and handed back however the routine ends,
Ctrl-C included. A lease taken and never renewed lapses and trips the enabled arm ("lease
lost"), so a Ctrl-C that comes while it is being taken is held back until it is, then raised
where the lease is handed back."""
from __future__ import annotations

import signal
import threading
from contextlib import contextmanager


@contextmanager
def routine_lease(client):
    """``with routine_lease(client):`` the routine's body, holding ``client``'s lease."""
    with _held_back() as held:
        client.acquire_lease()
        client.keep_lease()
    try:
        if held:
            raise KeyboardInterrupt
        yield
    finally:
        client.release_lease()


@contextmanager
def _held_back():
    """Ctrl-C (SIGINT) noted instead of raised inside the block; the list it yields is not
    empty afterwards if one came. In the main thread only (the one Python gives signals to)."""
    held: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield held
        return
    before = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        yield held
    finally:
        signal.signal(signal.SIGINT, before)
