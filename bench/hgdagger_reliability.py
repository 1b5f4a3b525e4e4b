"""HG-DAgger's reliability on pick-and-place: one run per seed, then a fresh evaluation of its final novice.

    MENAGERIE_ROOT=../shared/robots python bench/hgdagger_reliability.py --seeds 0,1,2,3 \\
        --out bench/results/local/phase2/hgdagger_reliability.json

Each seed runs ``unilab_jax/training/hgdagger.py`` on ``--envs`` in-process simulated Frankas (unpaced: robot time
is counted in steps, not measured) with the experiment's flags' meaning (``--demo_episodes``, ``--rounds``,
``--episodes_per_round``, ``--eval_episodes``, ``--ensemble``, ``--refit_steps``, ``--warm_start``,
``--keep_best``, ``--intervention_weight``, ``--novice_time``, ``--operator_segment``), then evaluates the
novice it ends with (the kept one under ``--keep_best``) alone on ``--fresh_episodes`` episodes of robots
seeded apart from the run's. Per seed: the success rate after the initial fit and after each round
(``eval_episodes`` each), the intervention rate per round, the fresh evaluation, and the robot time at 10 Hz
in minutes, split into the demonstrations and gated rounds (the operator's data) and the evaluations.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

import tasks
from unilab_jax.algos.imitation.bc import BCConfig
from unilab_jax.training.hgdagger import HGDagger, HGDaggerConfig

CONTROL_HZ = 10.0
FRESH_SEED_OFFSET = 1000  # the fresh evaluation's robots: seed + this (the run's robots use seed)


def robot_minutes(steps: int) -> float:
    return steps / CONTROL_HZ / 60.0


def run_seed(args: argparse.Namespace, seed: int) -> dict:
    config = HGDaggerConfig(demo_episodes=args.demo_episodes, rounds=args.rounds,
                            episodes_per_round=args.episodes_per_round, eval_episodes=args.eval_episodes,
                            intervention_weight=args.intervention_weight, warm_start=args.warm_start,
                            keep_best=args.keep_best, refit_steps=args.refit_steps, novice_time=args.novice_time,
                            bc=BCConfig(steps=args.bc_steps, ensemble=args.ensemble))
    t0 = time.perf_counter()
    task = tasks.make("robot_pick_place", args.envs, seed, {"operator_segment": args.operator_segment})
    try:
        loop = HGDagger(task, config, seed=seed)
        summary = loop.run()
    finally:
        task.close()
    fresh_task = tasks.make("robot_pick_place", args.envs, seed + FRESH_SEED_OFFSET, {})
    try:
        fresh = HGDagger(fresh_task, config, seed=seed).collect("off", loop.weights, args.fresh_episodes)
    finally:
        fresh_task.close()
    history = loop.history
    rounds = history[1:]
    eval_steps = sum(int(h["hgdagger/eval_steps"]) for h in history)
    return {
        "seed": seed, "success_rates": summary["success_rates"],
        "kept": [h.get("hgdagger/kept", 1.0) for h in history],
        "intervention_rates": [h["hgdagger/intervention_rate"] for h in rounds],
        "round_success_rates": [h["hgdagger/round_success_rate"] for h in rounds],
        "fresh_success_rate": fresh.success_rate, "fresh_episodes": len(fresh.successes),
        "robot_min_data": robot_minutes(summary["env_steps"] - eval_steps),
        "robot_min_evaluations": robot_minutes(eval_steps), "robot_min_fresh": robot_minutes(fresh.steps),
        "dataset_rows": summary["dataset_rows"], "wall_s": time.perf_counter() - t0,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--envs", type=int, default=4)
    p.add_argument("--demo_episodes", type=int, default=24)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--episodes_per_round", type=int, default=32)
    p.add_argument("--eval_episodes", type=int, default=40)
    p.add_argument("--fresh_episodes", type=int, default=80)
    p.add_argument("--ensemble", type=int, default=5)
    p.add_argument("--bc_steps", type=int, default=4000)
    p.add_argument("--refit_steps", type=int, default=4000)
    p.add_argument("--warm_start", action=argparse.BooleanOptionalAction, default=False)
    p.add_argument("--keep_best", action=argparse.BooleanOptionalAction, default=True)
    p.add_argument("--intervention_weight", type=int, default=1)
    p.add_argument("--novice_time", action=argparse.BooleanOptionalAction, default=False)
    p.add_argument("--operator_segment", type=int, default=20)
    p.add_argument("--out", default="")
    args = p.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    if args.envs < 1 or args.fresh_episodes < 1:
        p.error("--envs and --fresh_episodes must be positive")
    runs = []
    for seed in seeds:
        runs.append(run_seed(args, seed))
        print(json.dumps(runs[-1], default=float), flush=True)
    fresh = [r["fresh_success_rate"] for r in runs]
    result = {"config": vars(args), "runs": runs, "fresh_mean": float(np.mean(fresh)), "fresh_min": min(fresh),
              "machine": {"node": platform.node(), "cpus": os.cpu_count(), "load": os.getloadavg(),
                          "python": platform.python_version()}}
    print(json.dumps({k: result[k] for k in ("fresh_mean", "fresh_min")}))
    if args.out:
        os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1, default=float)


if __name__ == "__main__":
    main()
