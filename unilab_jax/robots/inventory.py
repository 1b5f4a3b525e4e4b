"""Robot inventories: which robots a run uses, local simulated servers for them, and discovery.

An inventory is a comma list (``--robots``) or a TOML file::

    sim:franka_emika_panda,sim:universal_robots_ur5e,tcp://192.168.1.20:5555

    # robots.toml
    [client]
    key = "keys/trainer.key_secret"       # this client's key pair (python -m unilab_jax.robots.keys new)
    [[robot]]
    sim = "franka_emika_panda"
    [[robot]]
    address = "tcp://192.168.1.20:5555"
    server_key = "keys/franka1.key"       # the server's public key: the server speaks CURVE

``sim:NAME`` starts a local robot server subprocess for the Menagerie model NAME (on a free loopback
port; the cameras a run's image observation needs, else none); ``tcp://HOST:PORT`` is a server that is
already running; with ``server_key`` (a ``.key`` file, relative to the TOML's folder) it is a keyed server,
reached with the ``[client] key`` (``robots.keys``; the server must admit that key). ``discover`` asks each
server for its spec and health (without claiming it) and refuses robots a policy cannot share (another task,
other observation or action sizes). Imports the standard library, zmq (keys) and this package only.
"""

from __future__ import annotations

import dataclasses
import os
import queue
import re
import subprocess
import sys
import threading
from typing import Any

from unilab_jax.robots import keys
from unilab_jax.robots.client import query
from unilab_jax.robots.gl import find_gl_backend
from unilab_jax.robots.interface import Health, RobotDisconnected, RobotSpec

# Menagerie model name -> arm of robots.scenes.ARMS.
SIM_ROBOTS = {"franka_emika_panda": "franka", "universal_robots_ur5e": "ur5e"}
START_TIMEOUT_S = 60.0
_ADDRESS = re.compile(r"^tcp://([A-Za-z0-9.\-]+|\[[0-9A-Fa-f:]+\]):(\d{1,5})$")


class InventoryError(ValueError):
    """A bad inventory, a server that does not answer, or robots that cannot share a policy."""


@dataclasses.dataclass(frozen=True)
class RobotEntry:
    """One inventory line: ``sim`` (the Menagerie name of a robot to simulate) or ``address``; a keyed server's
    ``server_key`` (its public key, Z85) and ``client_key`` (the path of the client's ``.key_secret``)."""

    sim: str = ""
    address: str = ""
    server_key: str = ""
    client_key: str = ""


    def __str__(self) -> str:
        return f"sim:{self.sim}" if self.sim else self.address


def check_address(address: str) -> str:
    m = _ADDRESS.match(address)
    if m is None or not 1 <= int(m.group(2)) <= 65535:
        raise InventoryError(f"bad robot address {address!r}: use tcp://HOST:PORT (port 1-65535)")
    return address


def _entry(item: str) -> RobotEntry:
    if item.startswith("sim:"):
        name = item[4:]
        if name not in SIM_ROBOTS:
            raise InventoryError(f"unknown simulated robot {name!r}; choose one of {sorted(SIM_ROBOTS)}")
        return RobotEntry(sim=name)
    if item.startswith("tcp://"):
        return RobotEntry(address=check_address(item))
    raise InventoryError(f"bad robot {item!r}: use sim:NAME ({', '.join(sorted(SIM_ROBOTS))}) or tcp://HOST:PORT")


def parse(text: str) -> list[RobotEntry]:
    """``--robots`` (a comma list, or the path of a ``.toml`` file) -> entries (at least one)."""
    text = text.strip()
    if text.endswith(".toml"):
        try:
            import tomllib
        except ImportError as e:  # Python 3.10
            raise InventoryError(f"robot inventory {text!r}: TOML files need Python 3.11+; give a comma list") from e
        try:
            with open(text, "rb") as f:
                doc = tomllib.load(f)
        except (OSError, tomllib.TOMLDecodeError) as e:
            raise InventoryError(f"robot inventory {text!r}: {e}") from e
        entries = _toml_entries(text, doc)
    else:
        items = [item.strip() for item in text.split(",")]
        if any(not item for item in items):
            raise InventoryError(f"no robots in {text!r}: give e.g. sim:franka_emika_panda,tcp://127.0.0.1:5555")
        entries = [_entry(item) for item in items]
    addresses = [e.address for e in entries if e.address]
    if len(set(addresses)) != len(addresses):
        raise InventoryError(f"a robot address is listed twice in {text!r}")
    return entries


def _toml_entries(path: str, doc: dict) -> list[RobotEntry]:
    rows, client = doc.get("robot"), doc.get("client", {})
    if not isinstance(rows, list) or not rows or not all(isinstance(r, dict) for r in rows):
        raise InventoryError(f"robot inventory {path!r}: needs [[robot]] tables with sim = NAME or address = URL")
    if set(doc) - {"robot", "client"} or not isinstance(client, dict) or set(client) - {"key"}:
        raise InventoryError(f"robot inventory {path!r}: only [client] key = FILE and [[robot]] tables are known")
    folder = os.path.dirname(os.path.abspath(path))
    client_key = os.path.join(folder, str(client["key"])) if "key" in client else ""
    entries = []
    for r in rows:
        kind = set(r) - {"server_key"}
        if kind not in ({"sim"}, {"address"}) or not all(isinstance(v, str) for v in r.values()):
            raise InventoryError(f"robot inventory {path!r}: each [[robot]] has sim = NAME or address = URL (and a "
                                 f"server its server_key = FILE), got {r}")
        entry = _entry(f"sim:{r['sim']}" if "sim" in r else r["address"])
        if "server_key" in r:
            if entry.sim:
                raise InventoryError(f"robot inventory {path!r}: sim robots run here without keys, got {r}")
            if not client_key:
                raise InventoryError(f"robot inventory {path!r}: {entry.address} has a server_key, so the inventory "
                                     "needs [client] key = FILE (this client's NAME.key_secret)")
            try:
                server_key = keys.load_public(os.path.join(folder, r["server_key"])).decode()
                keys.load_pair(client_key)
            except keys.KeyFileError as e:
                raise InventoryError(f"robot inventory {path!r}: {e}") from e
            entry = dataclasses.replace(entry, server_key=server_key, client_key=client_key)
        entries.append(entry)
    return entries


class LocalServer:
    """A ``python -m unilab_jax.robots.serve`` subprocess on a free loopback port (rendering ``cameras`` at
    ``image_size``, the arm drawn with its ``camera_geometry``; no cameras by default); it stops by itself when the
    process that started it dies, even by SIGKILL (``--exit_with_parent``)."""

    def __init__(self, arm: str, task: str, speed: float, seed: int = 0, port: int = 0,
                 extra: tuple[str, ...] = ("--dense_reward",), cameras: tuple[str, ...] = (), image_size: int = 64,
                 env: dict[str, str] | None = None, camera_geometry: str = "visual"):
        cmd = [sys.executable, "-m", "unilab_jax.robots.serve", f"--robot={arm}", f"--task={task}",
               f"--speed={speed}", f"--cameras={','.join(cameras) or 'none'}", f"--image_size={image_size}",
               f"--camera_geometry={camera_geometry}", "--host=127.0.0.1", f"--port={port}", f"--seed={seed}",
               "--exit_with_parent", *extra]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env={**os.environ, "OMP_NUM_THREADS": "1", **(env or {})})
        self.stderr = ""
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: lines.put(self.proc.stdout.readline()), daemon=True).start()
        try:
            line = lines.get(timeout=START_TIMEOUT_S)
        except queue.Empty:
            self.stop()
            raise InventoryError(f"robot server {arm}/{task} did not start within {START_TIMEOUT_S:.0f} s") from None
        if not line.startswith("serving "):
            self.stop()
            raise InventoryError(f"robot server {arm}/{task} failed to start (exit {self.proc.returncode}): "
                                 f"{(line + self.stderr)[-2000:]}")
        self.address = line.split(" on ")[1].strip()

    def stop(self) -> int:
        """SIGTERM, then SIGKILL after 5 s; returns the exit status (what the server wrote to stderr: ``stderr``)."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        if not self.proc.stderr.closed:
            self.stderr = self.proc.stderr.read()
        for stream in (self.proc.stdout, self.proc.stderr):
            stream.close()
        return self.proc.returncode


class Inventory:
    """Starts the local servers of ``entries`` (``with Inventory(...) as inv: inv.addresses``); stops them
    on exit, also when starting one of them fails (``dense_reward``: the servers' reward, else success only;
    ``cameras`` / ``image_size`` / ``camera_geometry``: what they render)."""

    def __init__(self, entries: list[RobotEntry], task: str, speed: float, seed: int = 0, dense_reward: bool = True,
                 cameras: tuple[str, ...] = (), image_size: int = 64, camera_geometry: str = "visual"):
        self.entries, self.task, self.speed, self.seed = entries, task, speed, seed
        self.extra = ("--dense_reward",) if dense_reward else ()
        self.cameras, self.image_size, self.camera_geometry = tuple(cameras), image_size, camera_geometry
        self.servers: list[LocalServer] = []
        self.addresses: list[str] = []

    def __enter__(self) -> Inventory:
        env = {}
        if self.cameras and any(e.sim for e in self.entries) and "MUJOCO_GL" not in os.environ:
            backend, reasons = find_gl_backend()  # once for all servers (each would probe it on its own)
            if backend is None:
                raise InventoryError(f"sim: robots with cameras need an offscreen GL backend: {'; '.join(reasons)}")
            env["MUJOCO_GL"] = backend
        try:
            for i, e in enumerate(self.entries):
                if e.sim:
                    self.servers.append(LocalServer(SIM_ROBOTS[e.sim], self.task, self.speed, seed=self.seed + i,
                                                    extra=self.extra, cameras=self.cameras,
                                                    image_size=self.image_size, env=env,
                                                    camera_geometry=self.camera_geometry))
                    self.addresses.append(self.servers[-1].address)
                else:
                    self.addresses.append(e.address)
        except BaseException:
            self.close()
            raise
        return self

    def task_overrides(self) -> dict[str, Any]:
        """The robot task's fields for these robots: ``robots`` (the addresses) and the keys of keyed servers
        (``server_keys``, one per robot, "" for none; ``client_key``)."""
        server_keys = tuple(e.server_key for e in self.entries)
        return {"robots": tuple(self.addresses), "server_keys": server_keys if any(server_keys) else (),
                "client_key": next((e.client_key for e in self.entries if e.client_key), "")}

    def keyring(self) -> list[keys.ClientKeys | None]:
        """Per address, what a client needs to reach it (``discover``'s ``keyring``)."""
        o = self.task_overrides()
        return client_keys(o["server_keys"], o["client_key"])

    def close(self) -> None:
        for server in self.servers:
            server.stop()
        self.servers = []

    def __exit__(self, *exc) -> None:
        self.close()


@dataclasses.dataclass(frozen=True)
class Discovered:
    address: str
    spec: RobotSpec
    health: Health


def compatible(a: RobotSpec, b: RobotSpec) -> str:
    """"" when one policy can drive both robots, else what differs."""
    diffs = [f"{k} {getattr(a, k)} vs {getattr(b, k)}" for k in ("task", "proprio_dim", "privileged_dim", "action_dim")
             if getattr(a, k) != getattr(b, k)]
    return ", ".join(diffs)


def client_keys(server_keys: tuple[str, ...], client_key: str) -> list[keys.ClientKeys | None]:
    """Per robot, what a client needs to reach it (None for a server without keys); ``server_keys`` and
    ``client_key`` as in ``Inventory.task_overrides``. Raises ``keys.KeyFileError`` for an unreadable key file."""
    pair = keys.load_pair(client_key) if any(server_keys) else None
    return [keys.ClientKeys(*pair, k.encode()) if k and pair else None for k in server_keys]


def discover(addresses: list[str], task: str = "", timeout_s: float = 2.0,
             keyring: list[keys.ClientKeys | None] | None = None) -> list[Discovered]:
    """Each server's spec and health (not claimed; ``keyring``: per address, the keys of a keyed server). Raises
    InventoryError for a server that does not answer, a robot serving another ``task`` (when given), or robots
    that cannot share one policy."""
    found = []
    for i, address in enumerate(addresses):
        try:
            spec, health = query(address, timeout_s=timeout_s, keys=keyring[i] if keyring else None)
        except RobotDisconnected as e:
            raise InventoryError(f"no robot server answers at {address} ({e})") from e
        if task and spec.task != task:
            raise InventoryError(f"{address} serves {spec.name} on task {spec.task!r}, this run needs {task!r}")
        if found and (diff := compatible(found[0].spec, spec)):
            raise InventoryError(f"{address} ({spec.name}) cannot share a policy with {found[0].address} "
                                 f"({found[0].spec.name}): {diff}")
        found.append(Discovered(address, spec, health))
    return found
