"""How often a Go1 holding its default pose (zero action) falls on the rough task's terrain, per terrain type, under
task-config variants (issue 33's diagnosis of a FastSAC run that never learnt to track on level 0): terminations per
1000 env steps of ``--envs`` robots over ``--steps`` control steps, every robot on ``--level`` (curriculum off).

    python bench/rough_standing_falls.py --out bench/results/local/phase3/rough_standing_falls.json \\
        --variant base= --variant no_dr=domain_randomization=False --variant no_com=dr_com_offset=0.0

``--variant NAME=K=V;K=V`` (empty after the first ``=``: the task's defaults; values as Python literals);
``go1_joystick_flat`` is measured beside them (``--flat``) as the reference.
"""

from __future__ import annotations

import argparse
import ast
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from machine import host_info, write_json  # noqa: E402


def falls(task_name: str, overrides: dict, envs: int, steps: int, level: int | None, seed: int) -> dict:
    """Terminations of zero-action robots: in all, per 1000 env steps, and per terrain type for the rough task."""
    import tasks

    task = tasks.make(task_name, envs, seed, overrides)
    try:
        rough = getattr(task, "rough", None)
        if rough is not None and level is not None:
            rough.levels[:] = level
        task.reset()
        columns = rough.terrain.columns if rough is not None else ("",)
        fell, seen = np.zeros(len(columns)), np.zeros(len(columns))  # per terrain column: falls, env steps
        zero = np.zeros((envs, task.spec.action_dim), np.float32)
        for _ in range(steps):
            cols = rough.cols.copy() if rough is not None else np.zeros(envs, int)  # where each env stepped
            out = task.step(zero)
            seen += np.bincount(cols, minlength=len(columns))
            fell += np.bincount(cols, weights=out.terminated, minlength=len(columns))
        total = int(fell.sum())
        out = {"terminations": total, "per_1000_env_steps": 1000.0 * total / (envs * steps)}
        if rough is not None:  # columns of one terrain type counted together
            names = np.array(columns)
            by_type = {t: (fell[names == t].sum(), seen[names == t].sum()) for t in set(columns)}
            out["per_type_per_1000"] = {t: round(1000.0 * f / n, 3) for t, (f, n) in sorted(by_type.items()) if n}
        return out
    finally:
        close = getattr(task, "close", None)
        if close:
            close()


def is_rough(task_name: str) -> bool:
    """Whether ``task_name`` is a rough-terrain task (its config has a terrain curriculum)."""
    import tasks

    return hasattr(tasks.default_config(task_name), "terrain_curriculum")


def parse_variant(spec: str) -> tuple[str, dict]:
    name, sep, rest = spec.partition("=")
    if not sep or not name:
        raise ValueError(f"--variant {spec!r}: expected NAME=K=V;K=V (or NAME= for the defaults)")
    overrides = {}
    for item in filter(None, rest.split(";")):
        k, eq, v = item.partition("=")
        if not eq:
            raise ValueError(f"--variant {spec!r}: {item!r} is not K=V")
        try:
            overrides[k] = ast.literal_eval(v)
        except (ValueError, SyntaxError):
            overrides[k] = v
    return name, overrides


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--variant", action="append", default=[], help="NAME=K=V;K=V (repeatable)")
    ap.add_argument("--task", default="go1_joystick_rough")
    ap.add_argument("--envs", type=int, default=120)
    ap.add_argument("--steps", type=int, default=1200)
    ap.add_argument("--level", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--flat", default="go1_joystick_flat", help="reference task ('' to skip)")
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    try:
        variants = [parse_variant(v) for v in args.variant or ["base="]]
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2

    rows = []
    # the curriculum off where the task has one (the flat task's variants are measured the same way)
    common = {"terrain_curriculum": False} if is_rough(args.task) else {}
    for name, overrides in variants:
        t0 = time.perf_counter()
        r = falls(args.task, {**common, **overrides}, args.envs, args.steps, args.level, args.seed)
        rows.append({"variant": name, "task": args.task, "overrides": {k: repr(v) for k, v in overrides.items()}, **r,
                     "seconds": round(time.perf_counter() - t0, 1)})
        print(f"{name:12s} {r['terminations']:5d} falls, {r['per_1000_env_steps']:.2f} per 1000 env steps")
    if args.flat:
        r = falls(args.flat, {}, args.envs, args.steps, None, args.seed)
        rows.append({"variant": "flat_reference", "task": args.flat, "overrides": {}, **r})
        print(f"{'flat':12s} {r['terminations']:5d} falls, {r['per_1000_env_steps']:.2f} per 1000 env steps")
    write_json(args.out, {"machine": host_info(), "envs": args.envs, "steps": args.steps, "level": args.level,
                          "seed": args.seed, "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
