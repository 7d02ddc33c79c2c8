"""CURVE on the daemon's sockets, in the messenger process: who may connect, and who sent
each request.

The Ironhouse pattern of ``zmq.auth``: every socket (command, control, telemetry) is a CURVE
server with the daemon's key pair, and ZeroMQ's authentication handler (``zmq.auth``'s
thread, in this process, never the loop's) admits a connection only if its client key is
on the allow-list (:class:`daemon.wire.keys.AllowList`). Each admitted message carries its
key's name (the ZAP User-Id); the messenger looks it up again per request, so a key
revoked and reloaded is refused at once, even on a connection made before; telemetry
subscribers are cut by re-binding the publisher, and a revoked one cannot come back.
"""
from __future__ import annotations

import logging

import zmq
from zmq.auth.thread import ThreadAuthenticator
from zmq.utils import z85

from daemon.wire.keys import AllowList, Identity, server_pair

DOMAIN = "pneumad"  # the ZAP domain of the daemon's sockets
log = logging.getLogger("pneumad")


class _Authenticator(ThreadAuthenticator):
    """zmq.auth's handler, naming each admitted key (its User-Id) from the allow-list."""

    def __init__(self, context: zmq.Context, allowed: AllowList):
        super().__init__(context, log=log)
        self.allowed = allowed

    def curve_user_id(self, client_public_key: bytes) -> str:
        identity = self.allowed.identity(z85.encode(client_public_key))
        return identity.name if identity is not None else ""


class Guard:
    def __init__(self, context: zmq.Context, directory: str):
        self.public, self._secret = server_pair(directory)
        self.allowed = AllowList(directory)
        self._say_problems()
        self._auth = _Authenticator(context, self.allowed)
        self._auth.start()
        self._auth.configure_curve_callback(DOMAIN, self.allowed)

    def secure(self, sock: zmq.Socket) -> None:
        """Make ``sock`` (before it binds) a CURVE server that asks this guard who may connect."""
        sock.curve_server = True
        sock.curve_secretkey, sock.curve_publickey = self._secret, self.public
        sock.zap_domain = DOMAIN.encode()

    def identify(self, frame: zmq.Frame) -> Identity | None:
        """Who sent this message: its key's identity now (None if the key has been revoked
        since the connection was admitted)."""
        return self.allowed.by_name(frame.get("User-Id"))

    def reload(self, who: str) -> dict:
        """Read the allow-list again (``who`` asked); what changed (names), as a reply and a
        log line say it."""
        added, removed, changed = self.allowed.reload()
        self._say_problems()
        log.info("keys reloaded by %s: %d allowed (added %s, removed %s, changed %s)", who, len(self.allowed.clients),
                 sorted(added) or "none", sorted(removed) or "none", sorted(changed) or "none")
        return {"allowed": sorted(c.name for c in self.allowed.clients.values()), "added": sorted(added),
                "removed": sorted(removed), "changed": sorted(changed), "problems": self.allowed.problems}

    def _say_problems(self) -> None:
        for problem in self.allowed.problems:
            log.warning("keys: %s (left out)", problem)

    def close(self) -> None:
        self._auth.stop()
