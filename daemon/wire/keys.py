"""CURVE keys for pneumad: the daemon's key pair, the allow-list of client keys, and the
certificate files both live in (ZeroMQ's ZPL certificate format, as ``zmq.auth`` and czmq
read and write it).

A daemon's key directory (``pneumad run --keys DIR``)::

    DIR/server.key_secret   the daemon's key pair (mode 0600): never leaves the PC
    DIR/server.key          its public key: every client needs it
    DIR/clients/NAME.key    one allowed client's public key, with its name and role

A client's key file (``NAME.key_secret``, mode 0600) holds its key pair and, in its metadata,
``server-key``: the daemon's public key, so that one file is all a client is given. A role
is ``operator`` (may take the lease and move the arm) or ``observer`` (reads, watches,
records and may e-stop; never takes the lease). See docs/protocol.md, "Keys".
"""
from __future__ import annotations

import datetime
import os
import re
from dataclasses import dataclass

import zmq
from zmq.auth import load_certificate

from hal.errors import ConfigError

ROLES = ("operator", "observer")
OPERATOR, OBSERVER = ROLES
SERVER_SECRET = "server.key_secret"
SERVER_PUBLIC = "server.key"
CLIENTS = "clients"
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.@-]{0,63}$")
_ENTRY = re.compile(r'^\s+([A-Za-z0-9_-]+)\s*=\s*"?(.*?)"?\s*$')


class KeyFileError(ConfigError):
    """A key file or directory that cannot be used, said with its path."""


@dataclass(frozen=True)
class Identity:
    """Who sent a request: an allowed key's name and role, or an anonymous client of a
    daemon without keys (name "")."""

    name: str = ""
    role: str = OPERATOR

    def __str__(self) -> str:
        return self.name or "anonymous"


ANONYMOUS = Identity()


def check_name(name: str) -> str:
    if not _NAME.match(name):
        raise KeyFileError(f"key name {name!r}: use 1-64 letters, digits, '_', '.', '@' or '-', starting with a "
                           f"letter or digit")
    return name


def check_role(role: str) -> str:
    if role not in ROLES:
        raise KeyFileError(f"role {role!r}: one of {', '.join(ROLES)}")
    return role


# -- certificate files ---------------------------------------------------------------------
def write_certificate(path: str, public: bytes, secret: bytes | None = None, metadata: dict | None = None) -> str:
    """Write a ZPL certificate (a secret one with mode 0600, created so: never readable by
    others even for a moment); refuses to overwrite."""
    kind = "Secret" if secret else "Public"
    lines = [f"#   ****  Generated on {datetime.datetime.now():%Y-%m-%d %H:%M:%S} by pneumad  ****",
             f"#   ZeroMQ CURVE {kind} Certificate", "", "metadata"]
    lines += [f'    {key} = "{value}"' for key, value in (metadata or {}).items()]
    lines += ["curve", f'    public-key = "{public.decode()}"']
    if secret:
        lines.append(f'    secret-key = "{secret.decode()}"')
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600 if secret else 0o644)
    except FileExistsError:
        raise KeyFileError(f"{path} exists already: remove it first if you mean to replace it") from None
    with os.fdopen(fd, "w") as f:
        f.write("\n".join(lines) + "\n")
    return path


def git_work_tree(path: str) -> str | None:
    """The git work tree ``path`` lies in (the nearest directory above it holding ``.git``), or None."""
    directory = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(os.path.join(directory, ".git")):
        if os.path.dirname(directory) == directory:
            return None
        directory = os.path.dirname(directory)
    return directory


def commit_warning(secret_path: str) -> str | None:
    """What to tell whoever just wrote a secret key file inside a git work tree (a checkout, where
    a ``git add -A`` would take it); None elsewhere."""
    tree = git_work_tree(secret_path)
    if tree is None:
        return None
    return (f"warning: {secret_path} holds a secret key and lies in the git work tree {tree}: it must never be "
            f"committed (keep it out with a .gitignore line `*.key_secret`, as pneumad's own checkout does, or keep "
            f"keys outside the work tree)")


def read_metadata(path: str) -> dict[str, str]:
    """The ``metadata`` section of a certificate file."""
    meta, section = {}, None
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            if not line[0].isspace():
                section = line.strip()
            elif section == "metadata" and (m := _ENTRY.match(line)):
                meta[m.group(1)] = m.group(2)
    return meta


def read_key_pair(path: str, need_secret: bool) -> tuple[bytes, bytes | None]:
    """(public, secret) from a certificate file, or a clear error naming it."""
    try:
        public, secret = load_certificate(path)
    except (OSError, ValueError) as exc:
        raise KeyFileError(f"key file {path}: {exc}") from None
    if need_secret and not secret:
        raise KeyFileError(f"key file {path} holds no secret key: give the .key_secret file, not the public .key")
    for key in (public, secret):
        if key is not None and len(key) != 40:
            raise KeyFileError(f"key file {path}: a CURVE key is 40 Z85 characters, this one {len(key)}")
    return public, secret


def server_key_of(path: str) -> bytes:
    """The daemon's public key for a client: a ``server.key`` file, or the ``server-key``
    metadata of a client's own key file."""
    meta = read_metadata(path) if os.path.isfile(path) else {}
    if "server-key" in meta:
        return meta["server-key"].encode()
    return read_key_pair(path, need_secret=False)[0]


# -- the daemon's key directory ------------------------------------------------------------
def init_server(directory: str) -> tuple[str, str]:
    """Make the daemon's key pair and the empty allow-list; (public, secret) file paths."""
    os.makedirs(os.path.join(directory, CLIENTS), mode=0o755, exist_ok=True)
    public, secret = zmq.curve_keypair()
    secret_path = write_certificate(os.path.join(directory, SERVER_SECRET), public, secret, {"name": "pneumad"})
    return write_certificate(os.path.join(directory, SERVER_PUBLIC), public, None, {"name": "pneumad"}), secret_path


def server_pair(directory: str) -> tuple[bytes, bytes]:
    path = os.path.join(directory, SERVER_SECRET)
    if not os.path.isfile(path):
        raise KeyFileError(f"no daemon key pair in {directory}: make one with `pneumad keys init --keys {directory}`")
    if os.stat(path).st_mode & 0o077:
        raise KeyFileError(f"{path} is readable by others: `chmod 600 {path}` (its secret key is the daemon's "
                           f"identity)")
    return read_key_pair(path, need_secret=True)


def make_client(directory: str, name: str, role: str, out_dir: str) -> str:
    """A key pair for a client, made on the daemon's PC: its public key allowed here, its
    secret file (with the daemon's public key inside) written to ``out_dir`` to hand over."""
    check_name(name)
    check_role(role)
    server_public, _ = server_pair(directory)
    public, secret = zmq.curve_keypair()
    path = write_certificate(os.path.join(out_dir, f"{name}.key_secret"), public, secret,
                             {"name": name, "role": role, "server-key": server_public.decode()})
    allow(directory, name, role, public)
    return path


def new_client_pair(out_dir: str, name: str, server_key_file: str | None = None) -> tuple[str, str]:
    """A client's own key pair, made on its own machine (the secret never travels): send the
    public ``NAME.key`` to the lab to be allowed. (public, secret) file paths."""
    check_name(name)
    os.makedirs(out_dir, mode=0o700, exist_ok=True)
    public, secret = zmq.curve_keypair()
    meta = {"name": name}
    if server_key_file:
        meta["server-key"] = server_key_of(server_key_file).decode()
    secret_path = write_certificate(os.path.join(out_dir, f"{name}.key_secret"), public, secret, meta)
    return write_certificate(os.path.join(out_dir, f"{name}.key"), public, None, {"name": name}), secret_path


def allow(directory: str, name: str, role: str, public: bytes) -> str:
    """Put a client's public key on the allow-list (takes effect at the next reload)."""
    check_name(name)
    check_role(role)
    clients = os.path.join(directory, CLIENTS)
    if not os.path.isdir(clients):
        raise KeyFileError(f"{clients} does not exist: make the daemon's keys first (`pneumad keys init`)")
    if AllowList(directory).by_name(name) is not None:
        raise KeyFileError(f"a key named {name!r} is allowed already: revoke it first to replace it")
    return write_certificate(os.path.join(clients, f"{name}.key"), public, None, {"name": name, "role": role})


def revoke(directory: str, name: str) -> str:
    """Take a client's key off the allow-list (takes effect at the next reload)."""
    path = os.path.join(directory, CLIENTS, f"{check_name(name)}.key")
    try:
        os.remove(path)
    except FileNotFoundError:
        raise KeyFileError(f"no allowed key named {name!r} in {os.path.dirname(path)}") from None
    return path


class AllowList:
    """The allowed client keys of a key directory, by public key (Z85 bytes). Also the
    credentials provider of ``zmq.auth`` (``callback``), which asks from its own thread:
    a reload replaces the map in one assignment."""

    def __init__(self, directory: str):
        self.directory = directory
        self.clients: dict[bytes, Identity] = {}
        self._by_name: dict[str, Identity] = {}
        self.problems: list[str] = []
        self.reload()

    def reload(self) -> tuple[set[str], set[str], set[str]]:
        """Read the directory again; the names (added, removed, changed: still allowed, with
        another key or role, so that a connection made with the old key, or a lease taken in
        the old role, holds no more). A file that cannot be read is left out and said in
        ``problems``."""
        clients, problems = {}, []
        folder = os.path.join(self.directory, CLIENTS)
        for entry in sorted(os.listdir(folder)) if os.path.isdir(folder) else []:
            if not entry.endswith(".key"):
                continue
            path = os.path.join(folder, entry)
            try:
                public, _ = read_key_pair(path, need_secret=False)
                meta = read_metadata(path)
                identity = Identity(check_name(meta.get("name", entry[:-4])), check_role(meta.get("role", OPERATOR)))
            except (KeyFileError, OSError) as exc:
                problems.append(str(exc))
                continue
            clients[public] = identity
        before = {c.name: (public, c.role) for public, c in self.clients.items()}
        after = {c.name: (public, c.role) for public, c in clients.items()}
        self.clients, self.problems = clients, problems
        self._by_name = {c.name: c for c in clients.values()}
        return (after.keys() - before.keys(), before.keys() - after.keys(),
                {name for name in before.keys() & after.keys() if before[name] != after[name]})

    def callback(self, domain: str, key: bytes) -> bool:
        return key in self.clients

    def identity(self, public_z85: bytes) -> Identity | None:
        return self.clients.get(public_z85)

    def by_name(self, name: str) -> Identity | None:
        return self._by_name.get(name)


def secure_client(sock: zmq.Socket, key_file: str, server_key_file: str | None = None) -> None:
    """Make a client socket speak CURVE with the key pair in ``key_file`` (a NAME.key_secret)
    to the daemon whose public key is in ``server_key_file`` (a server.key), or in the key
    file's own ``server-key`` metadata."""
    public, secret = read_key_pair(key_file, need_secret=True)
    if server_key_file is None and "server-key" not in read_metadata(key_file):
        raise KeyFileError(f"{key_file} does not say the daemon's public key: give the daemon's server.key too "
                           f"(--server-key)")
    server = server_key_of(server_key_file or key_file)
    sock.curve_secretkey, sock.curve_publickey, sock.curve_serverkey = secret, public, server
