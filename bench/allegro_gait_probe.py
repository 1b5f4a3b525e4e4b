"""Can the Allegro hand of ``allegro_rotate`` turn its objects at all? A scripted open-loop finger gait, no
learning: prints a table, writes JSON.

    MENAGERIE_ROOT=../shared/robots python bench/allegro_gait_probe.py --out bench/results/local/allegro_gait_probe.json

The gait moves the index, middle and ring fingers (``--fingers``) through four phases of ``--phase_steps``
control steps each, as targets reached through the task's own relative actions (at most 1/24 rad a step):
press (medial and distal joints ``+press`` from the canonical pose) at spread ``-amp``, sweep to spread
``+amp`` pressed, lift (``-press``), sweep back lifted (the ring finger's spread mirrored). Each
(press, amp) pair runs ``--envs`` envs of the task's object distribution for one 400-step episode and
reports the metric of ``eval/rotation_rate`` / ``eval/time_to_fall`` (``RotationTracker``) and the fastest
env's rate. A rate well above the 0.2 rad/s goal says the hand, gains and action scale can rotate the
objects and the limit is the learning; the spread over envs says how much the object's size matters.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO not in sys.path:
    sys.path.insert(0, REPO)

from time_to_target import machine_info  # noqa: E402

import tasks  # noqa: E402
from tasks import allegro_rotate as ar  # noqa: E402


def gait_targets(phase: int, fingers: tuple[int, ...], press: float, amp: float) -> np.ndarray:
    """[16] joint targets of gait ``phase`` (0 press, 1 sweep, 2 lift, 3 return)."""
    spread, depth = [(-amp, press), (amp, press), (amp, -press), (-amp, -press)][phase]
    goal = np.array(ar.CANONICAL_POSE)
    for f in fingers:
        b = 4 * f
        goal[b] = -spread if f == 2 else spread
        goal[b + 2:b + 4] += depth
    return goal


def run(fingers: tuple[int, ...], press: float, amp: float, phase_steps: int, envs: int, seed: int) -> dict:
    task = tasks.make("allegro_rotate", envs, seed=seed)
    task.reset()
    tracker = task.eval_tracker()
    scale = task.config.action_scale
    per_env = np.zeros(envs)
    steps = np.zeros(envs)
    k = 0
    while not tracker.done:
        goal = gait_targets((k // phase_steps) % 4, fingers, press, amp)
        action = np.clip((goal - task.info["target"]) / scale, -1.0, 1.0).astype(np.float32)
        active = tracker.active.copy()
        tracker.step(action)
        per_env += np.where(active, task.object_angvel_z, 0.0)
        steps += active
        k += 1
    task.close()
    rates = per_env / np.maximum(steps, 1)
    return {"fingers": fingers, "press": press, "amp": amp, **tracker.result(), "max_env_rate": float(rates.max()),
            "envs_turned": int(np.sum(np.abs(rates) > 0.05))}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fingers", type=int, nargs="+", default=[0, 1, 2], help="0 index, 1 middle, 2 ring")
    p.add_argument("--press", type=float, nargs="+", default=[0.2, 0.3, 0.4])
    p.add_argument("--amp", type=float, nargs="+", default=[0.2, 0.4])
    p.add_argument("--phase_steps", type=int, default=10)
    p.add_argument("--envs", type=int, default=16)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="")
    args = p.parse_args()
    if not set(args.fingers) <= {0, 1, 2} or args.phase_steps < 1 or args.envs < 1:
        p.error("--fingers from 0 1 2, --phase_steps and --envs positive")
    rows = [run(tuple(args.fingers), pr, a, args.phase_steps, args.envs, args.seed)
            for pr in args.press for a in args.amp]
    print(f"{'press':>6} {'amp':>5} {'rate rad/s':>10} {'ttf':>5} {'max env':>8} {'envs turned':>11}")
    for r in rows:
        print(f"{r['press']:6.2f} {r['amp']:5.2f} {r['rotation_rate']:10.3f} {r['time_to_fall']:5.2f} "
              f"{r['max_env_rate']:8.2f} {r['envs_turned']:>5}/{args.envs}")
    if args.out:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, "w") as f:
            json.dump({"args": vars(args), "rows": rows, "machine": machine_info()}, f, indent=1)


if __name__ == "__main__":
    main()
