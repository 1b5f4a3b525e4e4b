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
``--still`` adds a row of zero actions (the reset targets held): how long the start holds its object with no
policy at all, the floor under any policy's time to fall. ``--task_config K=V`` sets task fields (for HORA's start:
``grasp_cache=builtin reset_press=0``). Each row also reports ``fell``, the fraction of envs whose episode ended by
a fall, and ``fall_step_quartiles`` of those falls (control steps from the start, of 400).

    python bench/allegro_gait_probe.py --still --press 0.3 --amp 0.4 --envs 64 \
        --task_config grasp_cache=builtin reset_press=0 --out bench/results/local/allegro_gait_probe_grasp.json
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
from unilab_jax.config import ConfigError, parse_overrides  # noqa: E402


def gait_targets(phase: int, fingers: tuple[int, ...], press: float, amp: float) -> np.ndarray:
    """[16] joint targets of gait ``phase`` (0 press, 1 sweep, 2 lift, 3 return)."""
    spread, depth = [(-amp, press), (amp, press), (amp, -press), (-amp, -press)][phase]
    goal = np.array(ar.CANONICAL_POSE)
    for f in fingers:
        b = 4 * f
        goal[b] = -spread if f == 2 else spread
        goal[b + 2:b + 4] += depth
    return goal


def run(fingers: tuple[int, ...], press: float | None, amp: float, phase_steps: int, envs: int, seed: int,
        overrides: dict) -> dict:
    """One row: the gait (``press`` None: zero actions, the hand still) on ``envs`` envs for one episode each."""
    task = tasks.make("allegro_rotate", envs, seed=seed, overrides=overrides)
    task.reset()
    tracker = task.eval_tracker()
    scale = task.config.action_scale
    per_env = np.zeros(envs)
    steps = np.zeros(envs)
    k = 0
    while not tracker.done:
        if press is None:
            action = np.zeros((envs, task.spec.action_dim), np.float32)
        else:
            goal = gait_targets((k // phase_steps) % 4, fingers, press, amp)
            action = np.clip((goal - task.info["target"]) / scale, -1.0, 1.0).astype(np.float32)
        active = tracker.active.copy()
        tracker.step(action)
        per_env += np.where(active, task.object_angvel_z, 0.0)
        steps += active
        k += 1
    length = task.config.episode_length
    task.close()
    rates = per_env / np.maximum(steps, 1)
    falls = steps[steps < length]
    return {"fingers": fingers, "press": press, "amp": amp, **tracker.result(), "max_env_rate": float(rates.max()),
            "envs_turned": int(np.sum(np.abs(rates) > 0.05)), "fell": float(falls.size / envs),
            "fall_step_quartiles": np.percentile(falls, [25, 50, 75]).tolist() if falls.size else None}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fingers", type=int, nargs="+", default=[0, 1, 2], help="0 index, 1 middle, 2 ring")
    p.add_argument("--press", type=float, nargs="+", default=[0.2, 0.3, 0.4])
    p.add_argument("--amp", type=float, nargs="+", default=[0.2, 0.4])
    p.add_argument("--phase_steps", type=int, default=10)
    p.add_argument("--envs", type=int, default=16)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--still", action="store_true", help="also a row of zero actions (the hand still)")
    p.add_argument("--task_config", nargs="*", default=[], metavar="K=V", help="allegro_rotate config fields")
    p.add_argument("--out", default="")
    args = p.parse_args()
    if not set(args.fingers) <= {0, 1, 2} or args.phase_steps < 1 or args.envs < 1:
        p.error("--fingers from 0 1 2, --phase_steps and --envs positive")
    gaits = ([(None, 0.0)] if args.still else []) + [(pr, a) for pr in args.press for a in args.amp]
    try:
        overrides = parse_overrides(args.task_config)
        rows = [run(tuple(args.fingers), pr, a, args.phase_steps, args.envs, args.seed, overrides) for pr, a in gaits]
    except (ConfigError, ValueError) as e:
        p.error(f"--task_config: {e}")
    print(f"{'press':>6} {'amp':>5} {'rate rad/s':>10} {'ttf':>5} {'fell':>5} {'max env':>8} {'envs turned':>11}")
    for r in rows:
        press = "still" if r["press"] is None else f"{r['press']:.2f}"
        print(f"{press:>6} {r['amp']:5.2f} {r['rotation_rate']:10.3f} {r['time_to_fall']:5.2f} {r['fell']:5.2f} "
              f"{r['max_env_rate']:8.2f} {r['envs_turned']:>5}/{args.envs}")
    if args.out:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, "w") as f:
            json.dump({"args": vars(args), "rows": rows, "machine": machine_info()}, f, indent=1)


if __name__ == "__main__":
    main()
