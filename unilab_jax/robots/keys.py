"""CURVE key pairs for robot servers and their clients (ZeroMQ's ``zmq.auth`` certificate files)::

    python -m unilab_jax.robots.keys new NAME --dir DIR    # DIR/NAME.key (public) + DIR/NAME.key_secret
    python -m unilab_jax.robots.keys list --dir DIR        # every key in DIR: name, public key, secret or not

A server is started with its own ``.key_secret`` (``serve --key``) and a folder of the public ``.key`` files of
the clients it admits (``serve --allow``); a client needs its own ``.key_secret`` and the server's public key
(the inventory's ``[client] key`` and ``server_key``, ``robots.inventory``). Public keys are Z85 text (40
characters); a ``.key_secret`` file is written readable by its owner only.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

import zmq.auth


class KeyFileError(ValueError):
    """A key file that is missing or does not hold the key asked for."""


@dataclasses.dataclass(frozen=True)
class ClientKeys:
    """What a client needs to talk to a keyed server: its own pair and the server's public key (Z85 bytes)."""

    public: bytes
    secret: bytes
    server: bytes


def new(name: str, folder: str) -> tuple[str, str]:
    """Writes a fresh pair ``folder/name.key`` and ``folder/name.key_secret``; returns their paths. Refuses to
    overwrite an existing pair."""
    if not name or os.sep in name or name.startswith("."):
        raise KeyFileError(f"bad key name {name!r}: use a plain file name")
    public_file = os.path.join(folder, f"{name}.key")
    if os.path.exists(public_file) or os.path.exists(public_file + "_secret"):
        raise KeyFileError(f"{public_file} already exists: choose another name or remove the old pair")
    os.makedirs(folder, exist_ok=True)
    public_file, secret_file = zmq.auth.create_certificates(folder, name)
    os.chmod(secret_file, 0o600)
    return public_file, secret_file


def load_public(path: str) -> bytes:
    """The public key (Z85) of a ``.key`` or ``.key_secret`` file."""
    public, _ = _load(path)
    return public


def load_pair(path: str) -> tuple[bytes, bytes]:
    """(public, secret) of a ``.key_secret`` file."""
    public, secret = _load(path)
    if not secret:
        raise KeyFileError(f"{path} holds no secret key (give the NAME.key_secret file)")
    return public, secret


def load_allowed(folder: str) -> frozenset[bytes]:
    """The public keys of every ``*.key`` file in ``folder`` (a server's allow-list); at least one."""
    if not os.path.isdir(folder):
        raise KeyFileError(f"allow-list folder {folder!r} does not exist")
    try:
        keys = frozenset(zmq.auth.load_certificates(folder))
    except (OSError, ValueError) as e:
        raise KeyFileError(f"allow-list folder {folder!r}: {e}") from e
    if not keys:
        raise KeyFileError(f"no client public keys (*.key) in {folder!r}: copy the clients' NAME.key files there")
    return keys


def _load(path: str) -> tuple[bytes, bytes | None]:
    try:
        public, secret = zmq.auth.load_certificate(path)
    except (OSError, ValueError) as e:
        raise KeyFileError(f"cannot read key file {path!r}: {e}") from e
    if not public or len(public) != 40:
        raise KeyFileError(f"{path!r} holds no CURVE public key (make one: python -m unilab_jax.robots.keys new NAME)")
    return public, secret


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m unilab_jax.robots.keys", description=__doc__.split("::")[0])
    sub = p.add_subparsers(dest="command", required=True)
    made = sub.add_parser("new", help="make a key pair NAME.key + NAME.key_secret")
    made.add_argument("name")
    made.add_argument("--dir", default="keys")
    listed = sub.add_parser("list", help="list the keys in a folder")
    listed.add_argument("--dir", default="keys")
    args = p.parse_args(argv)
    try:
        if args.command == "new":
            public_file, secret_file = new(args.name, args.dir)
            print(f"{public_file}: public key {load_public(public_file).decode()} (give it out)")
            print(f"{secret_file}: secret key (keep it on this machine)")
            return 0
        if not os.path.isdir(args.dir):
            raise KeyFileError(f"no folder {args.dir!r}")
        names = sorted(f for f in os.listdir(args.dir) if f.endswith(".key"))
        for name in names:
            secret = os.path.exists(os.path.join(args.dir, name + "_secret"))
            public = load_public(os.path.join(args.dir, name)).decode()
            print(f"{name[:-4]:20s} {public}  {'public + secret' if secret else 'public only'}")
        if not names:
            print(f"no keys in {args.dir}")
        return 0
    except KeyFileError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
