"""Starts one robot server process::

    python -m unilab_jax.robots.serve --robot=franka --task=pick_place --port=5555 [--speed=1]
        [--host=0.0.0.0 --key=keys/franka1.key_secret --allow=keys/clients]
        [--workspace=0.2,-0.45,0,0.8,0.45,0.45 --cone_deg=60 --max_joint_speed=2 --max_tcp_speed=1 --max_force=400]
        [--latency_ms=20 --jitter_ms=5] [--cameras=front,wrist | --cameras=none] [--image_size=64]
        [--fault=drop:0.1] [--fault=stall_after:50] [--fault=exit_after:30]

Prints ``serving NAME on tcp://HOST:PORT`` (flushed) once it accepts requests (``--port=0``: a free
port), and exits cleanly on SIGTERM / SIGINT. A host other than loopback needs ``--key`` (the server's
``.key_secret``) and ``--allow`` (a folder of the admitted clients' public ``.key`` files; ``robots.keys``).
Every bad flag exits 2 with a one-line message. With cameras and no ``MUJOCO_GL`` set, the first backend of
``robots.gl.CANDIDATES`` that renders is used (egl works with software Mesa, no display needed).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading

from unilab_jax.robots.gl import find_gl_backend

LIMIT_FLAGS = {"cone_deg": "max tilt of the tcp from pointing down (degrees)",
               "max_joint_speed": "joint speed limit (rad/s)", "max_tcp_speed": "tcp speed (m/s): protective stop",
               "max_force": "contact force (N): protective stop"}


def parse_faults(items: list[str]) -> dict[str, float | int]:
    """``["drop:0.1", "exit_after:30"]`` -> FaultConfig keyword arguments."""
    names = {"drop": ("drop_reply_prob", float), "stall_after": ("stall_after_steps", int),
             "exit_after": ("exit_after_steps", int)}
    out: dict[str, float | int] = {}
    for item in items:
        kind, _, value = item.partition(":")
        if kind not in names or not value:
            raise ValueError(f"bad --fault {item!r}: use drop:P, stall_after:N or exit_after:N")
        field, typ = names[kind]
        out[field] = typ(value)
    return out


def parse_limits(args: argparse.Namespace):
    """The safety-limit flags -> ``robots.limits.SafetyLimits`` (ValueError naming the bad one). Imports mujoco:
    call it once ``MUJOCO_GL`` is set."""
    from unilab_jax.robots.limits import SafetyLimits

    given = {name: getattr(args, name) for name in LIMIT_FLAGS if getattr(args, name) is not None}
    if args.workspace:
        try:
            values = [float(v) for v in args.workspace.split(",")]
        except ValueError:
            values = []
        if len(values) != 6:
            raise ValueError(f"--workspace needs 6 numbers x0,y0,z0,x1,y1,z1, got {args.workspace!r}")
        given.update(box_low=tuple(values[:3]), box_high=tuple(values[3:]))
    return SafetyLimits(**given)


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m unilab_jax.robots.serve", description=__doc__.split("::")[0])
    p.add_argument("--robot", required=True, help="arm: franka or ur5e")
    p.add_argument("--task", required=True, help="peg_insertion, pick_place or reach")
    p.add_argument("--name", default="", help="robot name (default ARM_TASK)")
    p.add_argument("--host", default="127.0.0.1", help="IP address to listen on (not loopback: needs --key, --allow)")
    p.add_argument("--key", default="", help="the server's NAME.key_secret (python -m unilab_jax.robots.keys)")
    p.add_argument("--allow", default="", help="folder of the public NAME.key files of the clients to admit")
    p.add_argument("--workspace", default="", help="tcp box x0,y0,z0,x1,y1,z1 (m; default robots.limits)")
    for name, what in LIMIT_FLAGS.items():
        p.add_argument(f"--{name}", type=float, default=None, help=f"{what} (default: robots.limits.SafetyLimits)")
    p.add_argument("--port", type=int, default=0)
    p.add_argument("--speed", type=float, default=1.0, help="wall-clock speed-up of the control loop")
    p.add_argument("--latency_ms", type=float, default=0.0, help="actuator latency (simulated ms)")
    p.add_argument("--jitter_ms", type=float, default=0.0, help="std of the extra |normal| latency (ms)")
    p.add_argument("--noise", type=float, default=0.001, help="std of the proprioceptive noise")
    p.add_argument("--cameras", default="front,wrist", help="comma-separated camera names, or none")
    p.add_argument("--image_size", type=int, default=64)
    p.add_argument("--camera_geometry", default="visual", help="what the cameras draw of the arm: visual (its meshes) "
                   "or collision (its collision shapes, ~10x cheaper in software GL)")
    p.add_argument("--reset_s", type=float, default=2.0, help="reset duration at speed 1 (s)")
    p.add_argument("--dense_reward", action="store_true")
    p.add_argument("--lease_s", type=float, default=5.0)
    p.add_argument("--max_message_bytes", type=int, default=1 << 20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--fault", action="append", default=[], help="drop:P | stall_after:N | exit_after:N")
    p.add_argument("--exit_with_parent", action="store_true",
                   help="stop when the process that started this server dies (local servers of a run)")
    return p.parse_args(argv)


def _watch_parent(parent: int, stop: threading.Event, period_s: float = 0.25) -> None:
    """Sets ``stop`` once ``parent`` is gone: an orphan is re-parented, so ``getppid`` changes (also after a
    SIGKILL of the parent, which runs no clean-up of its own)."""
    while not stop.wait(period_s):
        if os.getppid() != parent:
            stop.set()  # first: the parent held our stdout/stderr pipes, so writing may fail now
            with contextlib.suppress(OSError):
                print(f"parent process {parent} is gone: stopping", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    cameras = () if args.cameras in ("", "none") else tuple(args.cameras.split(","))
    if cameras and "MUJOCO_GL" not in os.environ:  # must be set before mujoco is imported
        backend, reasons = find_gl_backend()
        if backend is None:
            print(f"error: no offscreen GL backend for the cameras ({'; '.join(reasons)}); use --cameras=none",
                  file=sys.stderr)
            return 2
        os.environ["MUJOCO_GL"] = backend
    from unilab_jax.robots.server import FaultConfig, RobotServer, ServerConfig
    from unilab_jax.robots.sim import SimConfig, SimRobot

    try:
        if args.seed < 0:
            raise ValueError(f"--seed must be >= 0, got {args.seed}")
        config = ServerConfig(host=args.host, port=args.port, lease_s=args.lease_s,
                              max_message_bytes=args.max_message_bytes, faults=FaultConfig(**parse_faults(args.fault)),
                              seed=args.seed, key_file=args.key, allow_dir=args.allow)
        sim = SimConfig(arm=args.robot, task=args.task, name=args.name, speed=args.speed,
                        latency_s=args.latency_ms / 1000, jitter_s=args.jitter_ms / 1000, proprio_noise=args.noise,
                        cameras=cameras, image_size=args.image_size, camera_geometry=args.camera_geometry,
                        reset_seconds=args.reset_s,
                        dense_reward=args.dense_reward, seed=args.seed, limits=parse_limits(args))
        robot = SimRobot(sim)
        server = RobotServer(robot, config)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    robot.connect()
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    if args.exit_with_parent:
        threading.Thread(target=_watch_parent, args=(os.getppid(), stop), daemon=True).start()
    print(f"serving {robot.spec.name} on {server.address}", flush=True)
    try:
        server.serve(stop)
    finally:
        robot.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
