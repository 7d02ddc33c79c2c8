"""One daemon as the Bluesky side reaches it: the Python client run off the RunEngine's event
loop, ``describe`` read once, and one ``status`` shared by every signal read at one moment.

The client is synchronous (ZeroMQ requests, each with its time-out); the RunEngine is asyncio.
Every request goes through :meth:`RigLink.call`, in a worker thread, so a slow daemon never
blocks the event loop; the client's own lock keeps requests one at a time. A ``read`` of a
rig's signals reads the latest cycle record, which a background subscription to the ``state``
topic keeps (:meth:`RigLink.follow`); the state of the arm and the reference come from
``status``, asked once for readings taken within ``FRESH_S``.
"""
from __future__ import annotations

import asyncio
import threading
import time
from functools import partial

from daemon.client.client import Client
from daemon.wire.cycle_layout import CycleLayout

FRESH_S = 0.05  # one status answers every signal read within this [s]


class RigLink:
    """A daemon's endpoints and key, as ``pneumactl`` takes them (arguments, else the
    ``PNEUMAD_*`` environment variables, else the protocol's defaults)."""

    def __init__(self, command: str | None = None, control: str | None = None, telemetry: str | None = None,
                 key_file: str | None = None, server_key_file: str | None = None, timeout: float = 5.0):
        self.client = Client(command, control, telemetry, timeout=timeout, key_file=key_file,
                             server_key_file=server_key_file)
        self.describe: dict = {}
        self._status: dict = {}
        self._status_t = -1.0
        self._status_lock: asyncio.Lock | None = None
        self.contact: dict | None = None  # the array sensor's latest estimate (the contact topic's message)
        self.layout: CycleLayout | None = None  # the cycle record's (describe's), once followed
        self.row: dict = {}  # the latest cycle record, by field name (SI), once followed
        self._feed: threading.Thread | None = None
        self._stop_feed = threading.Event()

    @property
    def rig_name(self) -> str:
        return self.describe["rig"]["name"]

    def source(self, *path: str) -> str:
        """A signal's source: ``pneumad://<rig>/<joint or rig-level group>/<signal>``."""
        return "pneumad://" + "/".join((self.rig_name, *path))

    async def call(self, method: str, *args, **kwargs):
        """``Client.<method>(*args, **kwargs)`` in a worker thread (RemoteError, TimeoutError pass on)."""
        return await asyncio.to_thread(partial(getattr(self.client, method), *args, **kwargs))

    async def connect(self) -> None:
        """Reach the daemon and read its ``describe`` (what the device is built from)."""
        self.describe = await self.call("describe")

    async def status(self) -> dict:
        """The daemon's ``status``, fresh within FRESH_S."""
        if self._status_lock is None:
            self._status_lock = asyncio.Lock()
        async with self._status_lock:
            if time.monotonic() - self._status_t > FRESH_S:
                self._status = await self.call("status")
                self._status_t = time.monotonic()
            return self._status

    def forget_status(self) -> None:
        """The next read asks the daemon again (after a command changed what it would say)."""
        self._status_t = -1.0

    def follow(self, contact: bool = False) -> None:
        """Keep :attr:`row` at the daemon's latest cycle record (by field name, SI, through
        :attr:`layout`) and, with ``contact``, :attr:`contact` at its latest contact estimate,
        from a background subscription (the state comes 100 times a second, not on request);
        returns once the first row is in (TimeoutError after the client's time-out)."""
        self.layout = self.client.layout()
        subscription = self.client.subscribe((b"state", b"contact") if contact else (b"state",))
        first = threading.Event()

        def feed():
            try:
                while not self._stop_feed.is_set():
                    received = subscription.receive(0.2)
                    if received is None:
                        continue
                    topic, message = received
                    if topic == "contact":
                        self.contact = message
                    elif message.get("layout") == self.layout.id:
                        self.row = {name: message[name][-1] for name in self.layout.names}
                        first.set()
            finally:
                subscription.close()

        self._feed = threading.Thread(target=feed, name="pneumad-state", daemon=True)
        self._feed.start()
        if not first.wait(self.client.timeout):
            raise TimeoutError(f"{self.rig_name}: no state message in the daemon's layout within "
                               f"{self.client.timeout:g} s ({self.client.endpoints['telemetry']})")

    def close(self) -> None:
        self._stop_feed.set()
        if self._feed is not None:
            self._feed.join(2.0)
        if self.client.lease is not None:
            try:
                self.client.release_lease()
            except Exception:  # closing: the daemon may be gone; the lease then lapses on its own
                pass
        self.client.close()
