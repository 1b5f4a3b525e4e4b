"""How a walking policy trained on flat ground fares on the rough task's terrain, level by level and per terrain type
(issue 33's diagnosis: is level 0 of the rough task as easy as the flat floor, or does something in the rough task
itself stop a FastSAC run from ever learning to track there?).

    python bench/rough_policy_eval.py --policy policies/go1_walk.onnx --levels 0 3 6 9 \\
        --variant base= --variant no_dr=domain_randomization=False --out bench/results/local/phase3/rough_policy.json

The policy is an ONNX export (``python -m unilab_jax.export --format onnx``: input ``obs [B, obs_dim]``, output the
deterministic action) of a ``--flat`` task policy whose observation the rough task shares (Go1: 48 numbers). Per level
and variant, ``--envs`` robots (curriculum off, every robot on that level, robot ``i`` on terrain column ``i mod
columns``) run one episode each (``--seconds``) under the task's own command sampling; reported as the rough tasks'
evaluation reports it (``tasks/rough.py``'s ``evaluation_numbers``: tracking and yaw-rate errors, fall rate, overall
and per terrain type). The flat task is measured the same way as the reference. ``--variant NAME=K=V;K=V`` as in
``bench/rough_standing_falls.py``; ``--task`` may be a flat task too (its variants then vary the flat task: e.g. the
rough task's action latency on the flat floor, ``dr_action_delay=(0,1)``). ``--curriculum`` instead plays one whole
episode per robot and reports what the terrain curriculum would do with each (``curriculum_moves``)::

    python bench/rough_policy_eval.py --policy policies/go1_walk.onnx --curriculum --levels 0 --envs 140 \
        --flat '' --out bench/results/local/phase3/rough_policy_curriculum.json
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from machine import host_info, write_json
from rough_standing_falls import is_rough, parse_variant


def onnx_policy(path: str):
    """``obs [B, D] -> action [B, A]`` through onnxruntime (one thread: a bench on a small machine)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    session = ort.InferenceSession(path, opts, providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    return lambda obs: session.run(None, {name: np.asarray(obs, np.float32)})[0]


def episode(task, tracker, policy, steps: int) -> dict:
    """Steps ``task`` through ``tracker`` with ``policy`` until every env's first episode ended or ``steps``."""
    obs, _ = task.reset()
    for _ in range(steps):
        obs = tracker.step(policy(obs)).obs
        if tracker.done:
            break
    return tracker.result()


def numbers(task_name: str, overrides: dict, level: int, policy, envs: int, seconds: float, seed: int) -> dict:
    """The evaluation numbers of ``policy`` on ``task_name``: a rough task frozen on ``level`` (curricula off), a flat
    one through the walking tracker (``level`` unused)."""
    import tasks
    from tasks.walking_metric import WalkingTracker

    if is_rough(task_name):
        task, tracker = frozen(task_name, overrides, level, envs, seed)
    else:
        task = tasks.make(task_name, envs, seed, overrides)
        tracker = WalkingTracker(task)
    try:
        return episode(task, tracker, policy, round(seconds / task.spec.ctrl_dt))
    finally:
        task.close()


def frozen(task_name: str, overrides: dict, level: int, envs: int, seed: int):
    """(the rough task with every robot on ``level``, its evaluation tracker: curricula off, full command ranges)."""
    import tasks

    task = tasks.make(task_name, envs, seed, {**overrides, "terrain_curriculum": False})
    tracker = task.eval_tracker()
    task.rough.levels[:] = level
    return task, tracker


def curriculum_moves(task_name: str, overrides: dict, level: int, policy, envs: int, seed: int) -> dict:
    """What the terrain curriculum would do after one whole episode of ``policy`` on ``level`` (curricula frozen,
    full command ranges): the fractions of robots that fell, that walked past half a cell (``up``), that the task's
    rule demotes (``down``: less than half the reach of the commanded path) and that legged_gym's rule would demote
    (``down_path_length``: less than half of the mean |command| x the episode's duration), a robot that fell judged
    by its last standing step. Read one step before the time limit, so the state is the episode's."""
    from tasks import curriculum

    task, tracker = frozen(task_name, overrides, level, envs, seed)
    try:
        obs, _ = task.reset()
        r, length = task.rough, task.config.episode_length
        origins = r.origins(np.arange(envs))[:, :2]  # the cells stay put: the curriculum is off
        speed = np.zeros(envs)
        steps = np.zeros(envs)
        last = {"dist": np.zeros(envs), "reach": np.zeros(envs)}
        for _ in range(length - 1):
            active = tracker.active.copy()
            speed += np.where(active, np.linalg.norm(task.command[:, :2], axis=1), 0.0)
            obs = tracker.step(policy(obs)).obs
            steps += active
            still = tracker.active  # a robot that fell keeps its last standing step's numbers (auto-reset moved it)
            dist = np.linalg.norm(task.sim.qpos[:, :2] - origins, axis=1)
            last["dist"] = np.where(still, dist, last["dist"])
            last["reach"] = np.where(still, curriculum.asked_distance(r.commanded, steps, length), last["reach"])
            if tracker.done:
                break
        fell = ~tracker.active
        cell = r.config.terrain_cell_size
        up = last["dist"] > cell / 2
        down = (last["dist"] < last["reach"] / 2) & ~up
        by_length = (last["dist"] < speed * task.spec.ctrl_dt * length / np.maximum(steps, 1) / 2) & ~up
        return {"fell": float(fell.mean()), "up": float(up.mean()), "down": float(down.mean()),
                "down_path_length": float(by_length.mean()), "median_distance": float(np.median(last["dist"])),
                "median_reach": float(np.median(last["reach"]))}
    finally:
        task.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--policy", required=True, help="ONNX export of a --flat policy")
    ap.add_argument("--variant", action="append", default=[], help="NAME=K=V;K=V (repeatable)")
    ap.add_argument("--task", default="go1_joystick_rough")
    ap.add_argument("--flat", default="go1_joystick_flat", help="the reference task ('' to skip)")
    ap.add_argument("--levels", type=int, nargs="+", default=[0])
    ap.add_argument("--envs", type=int, default=70)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--curriculum", action="store_true",
                    help="instead: what the terrain curriculum would do after one whole episode (curriculum_moves)")
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    if not os.path.isfile(args.policy):
        print(f"error: --policy {args.policy!r}: no such file", file=sys.stderr)
        return 2
    try:
        variants = [parse_variant(v) for v in args.variant or ["base="]]
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    policy = onnx_policy(args.policy)
    rows = []
    keys = ("tracking_error", "yaw_rate_error", "fall_rate")
    if args.curriculum:
        if not is_rough(args.task):
            print(f"error: --curriculum needs a rough task, got {args.task!r}", file=sys.stderr)
            return 2
        for name, overrides in variants:
            for level in args.levels:
                r = curriculum_moves(args.task, overrides, level, policy, args.envs, args.seed)
                rows.append({"variant": name, "task": args.task, "level": level, **r})
                print(f"{name:10s} level {level}: " + ", ".join(f"{k} {v:.3f}" for k, v in r.items()))
        write_json(args.out, {"machine": host_info(), "policy": args.policy, "envs": args.envs, "seed": args.seed,
                              "curriculum": True, "rows": rows})
        return 0
    for name, overrides in variants:
        for level in args.levels:
            t0 = time.perf_counter()
            r = numbers(args.task, overrides, level, policy, args.envs, args.seconds, args.seed)
            rows.append({"variant": name, "task": args.task, "level": level,
                         "overrides": {k: repr(v) for k, v in overrides.items()}, **r,
                         "seconds": round(time.perf_counter() - t0, 1)})
            print(f"{name:10s} level {level}: " + ", ".join(f"{k} {r[k]:.3f}" for k in keys))
    if args.flat:
        r = numbers(args.flat, {}, 0, policy, args.envs, args.seconds, args.seed)
        rows.append({"variant": "flat_reference", "task": args.flat, **r})
        print("flat reference: " + ", ".join(f"{k} {r[k]:.3f}" for k in keys))
    write_json(args.out, {"machine": host_info(), "policy": args.policy, "envs": args.envs, "seconds": args.seconds,
                          "seed": args.seed, "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
