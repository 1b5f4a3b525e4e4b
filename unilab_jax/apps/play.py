"""Watch a trained policy: ``python -m unilab_jax.play --logdir DIR [--checkpoint STEP] [--video out.mp4]``.

Restores a run's checkpoint (``unilab_jax.apps.saved_run``), runs its deterministic policy on the run's task on
the CPU with numpy (the training-time worker policy), prints the return and length (and the walking metric
on locomotion tasks), and renders env 0 with ``mujoco.Renderer`` into an mp4 (imageio + imageio-ffmpeg).

Headless rendering: ``MUJOCO_GL`` must be chosen before mujoco is imported; on Linux this module sets it to
``egl`` unless it is already set (``osmesa`` where only that library is found, nothing where neither is:
``robots.gl.prefer_headless``). EGL runs on a GPU's driver or, on CPU-only machines, on Mesa's software
rasteriser (Debian/Ubuntu: ``apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0``). Set
``MUJOCO_GL=osmesa`` (needs libosmesa6) to use OSMesa instead.

Python API (notebooks): ``rollout_frames(logdir, ...) -> (frames [T, H, W, 3] uint8, stats)`` and
``write_video(frames, path, fps)``, both importable from here. ``write_video``, ``SceneRenderer`` and
``run_episodes`` live in ``unilab_jax.training.evaluation`` (the trainer's evaluations and clips use them too).
"""

from __future__ import annotations

from unilab_jax.robots.gl import prefer_headless

prefer_headless()  # before anything imports mujoco

import json  # noqa: E402
import logging  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
from collections.abc import Mapping  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from unilab_jax.apps import saved_run  # noqa: E402
from unilab_jax.training.evaluation import (  # noqa: E402  (the Python API names them here too)
    SceneRenderer,
    deterministic_policy,
    fps_of,
    run_episodes,
    video_writer_missing,
    write_video,
)

__all__ = ["SceneRenderer", "deterministic_policy", "fps_of", "main", "rollout_frames", "run_episodes", "run_policy",
           "write_video"]

log = logging.getLogger(__name__)


def run_policy(run: saved_run.SavedRun, *, episodes: int = 1, max_steps: int | None = None,
               render: tuple[int, int] | None = None, task_overrides: Mapping[str, Any] | None = None,
               seed: int = 0) -> tuple[np.ndarray, dict[str, Any]]:
    """:func:`run_episodes` of ``run``'s policy on ``episodes`` envs of its task (``task_overrides`` on top of
    the run's); the stats also name the algorithm, task, checkpoint and the real-time ``fps``."""
    if episodes < 1:
        raise ValueError(f"episodes must be at least 1, got {episodes}")
    task = run.make_task(episodes, seed=10_000 + seed, overrides=task_overrides)
    try:
        frames, stats = run_episodes(task, deterministic_policy(run.module, run.weights, task), max_steps=max_steps,
                                     render=render)
    finally:
        task.close()
    return frames, {"algo": run.algo, "task": run.task, "checkpoint": run.step, **stats, "fps": fps_of(run.spec)}


def rollout_frames(logdir: str, *, checkpoint: int | None = None, steps: int = 200, width: int = 320,
                   height: int = 240, task_overrides: Mapping[str, Any] | None = None,
                   seed: int = 0) -> tuple[np.ndarray, dict[str, Any]]:
    """Frames of one episode of the run's deterministic policy (at most ``steps`` control steps, one frame
    before each) and its stats (see :func:`run_policy`; ``stats["fps"]`` plays it in real time)."""
    run = saved_run.load(logdir, checkpoint, task_overrides)
    return run_policy(run, episodes=1, max_steps=steps, render=(width, height), task_overrides=task_overrides,
                      seed=seed)


def main(argv: list[str] | None = None) -> int:
    import argparse

    from unilab_jax.config import ConfigError, parse_overrides

    parser = argparse.ArgumentParser(prog="python -m unilab_jax.play", description=__doc__.split("\n")[0])
    parser.add_argument("--logdir", required=True, help="the training run's logdir")
    parser.add_argument("--checkpoint", type=int, default=None, help="env step of the checkpoint (default: latest)")
    parser.add_argument("--video", default="", help="write env 0's first episode to this mp4")
    parser.add_argument("--episodes", type=int, default=1, help="episodes (one env each) the stats average over")
    parser.add_argument("--steps", type=int, default=None, help="control steps per episode at most (default: the "
                        "task's episode length)")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--task_config", action="append", default=[], help="task override key=value (repeatable)")
    args = parser.parse_args(argv)
    if args.episodes < 1 or (args.steps is not None and args.steps < 1) or min(args.width, args.height) < 1:
        parser.error("--episodes, --steps, --width and --height must be positive")
    if args.video and (missing := video_writer_missing()) is not None:
        print(f"error: {missing}", file=sys.stderr)  # before the rollout, not after it
        return 2
    try:
        overrides = parse_overrides(args.task_config)
        run = saved_run.load(args.logdir, args.checkpoint, overrides)
        frames, stats = run_policy(run, episodes=args.episodes, max_steps=args.steps,
                                   render=(args.width, args.height) if args.video else None,
                                   task_overrides=overrides, seed=args.seed)
    except (FileNotFoundError, ConfigError, ValueError, NotImplementedError, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)  # RuntimeError: no GL backend; NotImplementedError: no scene
        return 2
    if args.video:
        write_video(frames, args.video, stats["fps"])
        stats.update(video=os.path.abspath(args.video), frames=int(frames.shape[0]))
    print(json.dumps(stats, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
