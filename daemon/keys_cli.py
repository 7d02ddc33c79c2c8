"""``pneumad keys``: the daemon's CURVE keys, on the daemon's PC (docs/protocol.md, "Keys").

    pneumad keys init                          the daemon's key pair and an empty allow-list
    pneumad keys client NAME [--role observer] a key pair for a client, allowed here, its file to hand over
    pneumad keys allow NAME.key [--role ...]   allow a public key a client made itself (pneumactl keys new)
    pneumad keys revoke NAME                   take a key off the allow-list
    pneumad keys list                          the allowed keys and their roles

Changes to the allow-list take effect at ``systemctl reload pneumad`` (SIGHUP) or
``pneumactl keys reload``.
"""
from __future__ import annotations

import os
import sys

from daemon.wire import keys

DEFAULT_DIR = "/etc/pneumad/keys"
RELOAD = "it takes effect once the daemon reloads its keys: `sudo systemctl reload pneumad` or `pneumactl keys reload`"


def add_parser(sub) -> None:
    k = sub.add_parser("keys", help="make and allow CURVE keys (docs/protocol.md, Keys)")
    k.add_argument("--keys", default=DEFAULT_DIR, metavar="DIR", help=f"the daemon's key directory (default {DEFAULT_DIR})")
    actions = k.add_subparsers(dest="action", required=True)
    actions.add_parser("init", help="make the daemon's key pair and an empty allow-list")
    c = actions.add_parser("client", help="make a client's key pair here, allow it, and write its file to hand over")
    c.add_argument("name")
    c.add_argument("--role", default=keys.OPERATOR, choices=keys.ROLES)
    c.add_argument("--out", default=".", help="where to write NAME.key_secret (default: here)")
    a = actions.add_parser("allow", help="allow a client's public key file (NAME.key)")
    a.add_argument("file")
    a.add_argument("--name", default=None, help="its name here (default: the file's own)")
    a.add_argument("--role", default=keys.OPERATOR, choices=keys.ROLES)
    r = actions.add_parser("revoke", help="take a client's key off the allow-list")
    r.add_argument("name")
    actions.add_parser("list", help="the allowed keys")


def run(args) -> int:
    """One ``pneumad keys`` action; a KeyFileError (a ConfigError) is the caller's to report."""
    directory = args.keys
    if args.action == "init":
        public, secret = keys.init_server(directory)
        print(f"the daemon's key pair: {secret} (mode 0600, stays here)\nits public key for clients: {public}\n"
              f"start the daemon with --keys {directory}")
        warn_if_committable(secret)
    elif args.action == "client":
        path = keys.make_client(directory, args.name, args.role, args.out)
        print(f"{path}: {args.name}'s key ({args.role}), with the daemon's public key inside. Hand it over privately "
              f"(it is a secret); they use it as `pneumactl --key {os.path.basename(path)}`.\n{RELOAD}")
        warn_if_committable(path)
    elif args.action == "allow":
        public, _ = keys.read_key_pair(args.file, need_secret=False)
        name = args.name or keys.read_metadata(args.file).get("name") or os.path.basename(args.file).split(".")[0]
        path = keys.allow(directory, name, args.role, public)
        print(f"allowed {name} ({args.role}): {path}\n{RELOAD}")
    elif args.action == "revoke":
        print(f"revoked: removed {keys.revoke(directory, args.name)}\n{RELOAD}")
    else:
        allowed = keys.AllowList(directory)
        for identity in sorted(allowed.clients.values(), key=lambda c: c.name):
            print(f"{identity.name:24s} {identity.role}")
        for problem in allowed.problems:
            print(f"(left out: {problem})")
        if not allowed.clients:
            print(f"no client keys are allowed in {directory}")
    return 0


def warn_if_committable(secret_path: str) -> None:
    """On stderr: a secret key file just written inside a git work tree must never be committed."""
    warning = keys.commit_warning(secret_path)
    if warning:
        print(warning, file=sys.stderr)
