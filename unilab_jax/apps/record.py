"""Records demonstrations through robot servers into a persistent replay store (prior data for RLPD)::

    python -m unilab_jax.robots.record --robots=sim:franka_emika_panda --task=robot_peg_insertion \\
        --episodes=20 --out=demos/peg [--speed=20] [--device=expert|keyboard|spacemouse]
        [--cameras=front,wrist --image_size=64 --frame_stack=2 --no_critic_state]

``--robots``: an inventory (``robots.inventory``: ``sim:NAME`` servers are started here at ``--speed``,
``tcp://HOST:PORT`` ones are already running). The robots run the task ``robots.robot_*`` as training
does (``tasks.robot``: same observations; the one-hot of each robot's place in the inventory only with
``--robot_identity``, as the robot experiments leave it out), so the transitions fit a training run on the same
inventory. A ``TeleopDevice`` (``robots.teleop``) drives
each robot: the scripted expert by default (robots in parallel), a keyboard (one robot).

With ``--cameras`` the task has its image observation (``tasks.robot``; ``sim:`` servers render those cameras
at ``--image_size``) and the transitions carry ``image`` / ``next_image`` (uint8 frame stacks) as well: record
with the image options of the training run that will load the demonstrations.

Output: a :class:`~unilab_jax.runtime.replay_store.ReplayStore` in ``--out`` (which must be empty) with
the prior-data fields of the task (``unilab_jax.fields.prior_fields``) plus per transition ``episode``
(int32, the episode's number in the recording) and ``success`` (bool, whether that episode succeeded:
its label). Only whole episodes are written, in the order they ended; the index's ``info`` names the
task, device and robots. Prints one JSON summary line (episodes, successes, transitions, robot seconds).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Any

import numpy as np

from unilab_jax.fields import IMAGE_FIELDS, prior_fields
from unilab_jax.robots import inventory, teleop

TASKS = ("robot_pick_place", "robot_peg_insertion", "robot_reach")
LABEL_FIELDS = {"episode": ((), np.dtype(np.int32)), "success": ((), np.dtype(bool))}


def demo_layout(spec: Any) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """The store's row layout for a task spec: the prior-data fields (with images where the task has them) and the
    labels."""
    from unilab_jax.runtime.buffers import transition_layout

    layout = transition_layout(spec)
    return {**{k: layout[k] for k in prior_fields(spec)}, **LABEL_FIELDS}


def record(addresses: list[str], task_name: str, episodes: int, out: str, device: str = "expert",
           seed: int = 0, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Records ``episodes`` whole episodes from the robot servers at ``addresses`` into a new store in ``out``
    (``overrides``: the task's, as the training run will give them)."""
    import tasks
    from unilab_jax.runtime.replay_store import ReplayStore

    if episodes < 1:
        raise ValueError(f"episodes must be positive, got {episodes}")
    if os.path.isdir(out) and os.listdir(out):
        raise ValueError(f"--out={out!r} is not empty: record into a new folder")
    if device != "expert" and len(addresses) != 1:
        raise ValueError(f"--device={device} drives one robot; the inventory has {len(addresses)}")
    task = tasks.make(task_name, num_envs=len(addresses), seed=seed,
                      overrides={**(overrides or {}), "robots": tuple(addresses)})
    devices = [teleop.make_device(device, task.robot_spec) for _ in addresses]
    t_start = time.perf_counter()
    try:
        store = ReplayStore(out, demo_layout(task.spec), info={"task": task_name, "device": device,
                                                                "robots": [r.spec.name for r in task.robots]})
        try:
            summary = _run(task, devices, store, episodes)
            store.flush()
        finally:
            store.close()
    finally:
        for d in devices:
            d.close()
        task.close()
    seconds = time.perf_counter() - t_start
    speed = task.robot_spec.speed
    summary.update({"task": task_name, "out": os.path.abspath(out), "seconds": round(seconds, 2),
                    "robot_seconds": round(summary["steps"] * task.spec.ctrl_dt, 2), "speed": speed})
    return summary


def _run(task: Any, devices: list, store: Any, episodes: int) -> dict[str, Any]:
    n = task.num_envs
    fields = prior_fields(task.spec)
    images = [k for k in IMAGE_FIELDS if k in fields]
    obs, critic = task.reset()
    for d in devices:
        d.reset()
    rows: list[list[dict[str, np.ndarray]]] = [[] for _ in range(n)]
    done_episodes = successes = steps = 0
    while done_episodes < episodes:
        action = np.stack([devices[i](task.observation(i)) for i in range(n)]).astype(np.float32)
        out = task.step(action)
        executed = out.extras.get("action", action) if out.extras else action  # e.g. with lock_rotation
        steps += n
        for i in range(n):
            rows[i].append({"obs": obs[i], "critic_obs": critic[i], "action": executed[i], "reward": out.reward[i],
                            "next_obs": out.next_obs[i], "next_critic_obs": out.next_critic_obs[i],
                            "terminated": out.terminated[i], "truncated": out.truncated[i],
                            **{k: out.extras[k][i] for k in images}})
            if (out.terminated[i] or out.truncated[i]) and done_episodes < episodes:
                success = bool(out.terminated[i])  # a robot task terminates on success only
                batch = {k: np.stack([r[k] for r in rows[i]]) for k in fields}
                batch["episode"] = np.full(len(rows[i]), done_episodes, np.int32)
                batch["success"] = np.full(len(rows[i]), success)
                store.append(batch)
                done_episodes += 1
                successes += success
            if out.terminated[i] or out.truncated[i]:
                rows[i] = []
                devices[i].reset()
        obs, critic = out.obs, out.critic_obs
    return {"episodes": done_episodes, "successes": successes, "transitions": store.committed + store.pending,
            "steps": steps}


def _check_terminal() -> None:
    try:
        os.close(os.open("/dev/tty", os.O_RDONLY))
    except OSError as e:
        raise ValueError(f"--device=keyboard reads keys from the terminal, and this process has none ({e})") from e


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m unilab_jax.robots.record", description=__doc__.split("::")[0])
    p.add_argument("--robots", default="sim:franka_emika_panda", help="inventory: comma list or .toml file")
    p.add_argument("--task", default="robot_peg_insertion", help=f"one of {TASKS}")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--out", required=True, help="new folder for the replay store")
    p.add_argument("--speed", type=float, default=20.0, help="speed-up of the sim: robots started here")
    p.add_argument("--device", default="expert", help=f"one of {teleop.DEVICES}")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--policy_state", action="store_true", help="record for runs with --task_config=policy_state=true")
    p.add_argument("--cameras", default="", help="image observation from these cameras (comma list of front, wrist; "
                   "empty: none): record for runs with the same --task_config=cameras")
    p.add_argument("--image_size", type=int, default=64, help="pixels per side of each camera frame (with --cameras)")
    p.add_argument("--frame_stack", type=int, default=1, help="frames per camera in the image (with --cameras)")
    p.add_argument("--no_critic_state", action="store_true", help="no privileged state in the critic observation: "
                   "record for runs with --task_config=critic_state=false (the image runs without --asymmetric)")
    p.add_argument("--robot_identity", action="store_true", help="the inventory-slot one-hot in the observation: "
                   "record for runs with --task_config=robot_identity=true (the robot experiments leave it out)")
    return p.parse_args(argv)


def task_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The task overrides of the flags (checked by the task's config: ValueError for bad image options)."""
    from tasks.robot import RobotTaskConfig

    cameras = tuple(c.strip() for c in args.cameras.split(",") if c.strip())
    overrides = {"policy_state": args.policy_state, "cameras": cameras, "image_size": args.image_size,
                 "frame_stack": args.frame_stack, "robot_identity": args.robot_identity,
                 "critic_state": not args.no_critic_state}
    RobotTaskConfig(**overrides)
    return overrides


def main(argv: list[str] | None = None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if args.task not in TASKS:
            raise ValueError(f"--task={args.task}: choose one of {TASKS}")
        if args.device not in teleop.DEVICES:
            raise ValueError(f"--device={args.device}: choose one of {teleop.DEVICES}")
        if args.device == "spacemouse":
            teleop.make_device("spacemouse", None)
        if args.device == "keyboard":
            _check_terminal()
        if not args.speed > 0 or args.speed == float("inf"):
            raise ValueError(f"--speed must be positive and finite, got {args.speed}")
        if args.episodes < 1:
            raise ValueError(f"--episodes must be positive, got {args.episodes}")
        if os.path.isdir(args.out) and os.listdir(args.out):
            raise ValueError(f"--out={args.out!r} is not empty: record into a new folder")
        entries = inventory.parse(args.robots)
        overrides = task_overrides(args)
    except (ValueError, teleop.SpaceMouseUnavailable) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    with inventory.Inventory(entries, args.task.removeprefix("robot_"), args.speed, seed=args.seed,
                             cameras=overrides["cameras"], image_size=args.image_size) as inv:
        summary = record(inv.addresses, args.task, args.episodes, args.out, args.device, args.seed,
                         {**overrides, **inv.task_overrides()})
    print(json.dumps(summary), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
