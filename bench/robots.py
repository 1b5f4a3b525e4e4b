"""Robot-server numbers: step latency over the wire, render time per frame, scripted-expert success.

    MENAGERIE_ROOT=../shared/robots python bench/robots.py [--episodes 50] [--out bench/results/robots.json]

* ``step_ms``: wall time of ``RobotClient.step`` against a ``python -m unilab_jax.robots.serve`` process
  (Franka pick-and-place, no cameras) at speed 1 and 20 (control period 100 ms and 5 ms).
* ``render_ms``: one ``mujoco.Renderer`` frame (front camera) of each arm at 64 and 96 px, in a fresh
  interpreter with the first working ``MUJOCO_GL`` backend (skipped when there is none).
* ``experts``: success rate of each scripted expert over ``--episodes`` episodes, in-process, unpaced.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from unilab_jax.robots.client import RobotClient
from unilab_jax.robots.experts import PAIRS, evaluate_expert
from unilab_jax.robots.gl import find_gl_backend

HOLD = np.array([0.0, 0, 0, 0, 0, 0, -1.0], dtype=np.float32)

_RENDER = """
import json, sys, time
from unilab_jax.robots.sim import SimConfig, SimRobot
out = {}
for arm in ("franka", "ur5e"):
    for size in (64, 96):
        robot = SimRobot(SimConfig(arm=arm, cameras=("front",), image_size=size, speed=float("inf"),
                                   reset_seconds=0.0))
        robot.reset(seed=0)
        r = robot._renderer
        r.update_scene(robot.data, camera="front"); r.render()
        t = time.perf_counter()
        for _ in range(20):
            r.update_scene(robot.data, camera="front"); r.render()
        out[f"{arm}_{size}px"] = (time.perf_counter() - t) / 20 * 1e3
        robot.close()
print(json.dumps(out))
"""


def step_latency(speed: float, steps: int) -> dict:
    cmd = [sys.executable, "-m", "unilab_jax.robots.serve", "--robot=franka", "--task=pick_place", "--port=0",
           f"--speed={speed}", "--cameras=none", "--reset_s=0.2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        address = proc.stdout.readline().split(" on ")[1].strip()
        with RobotClient(address, timeout_s=5.0) as robot:
            robot.reset(seed=0)
            times = []
            for _ in range(steps):
                t = time.perf_counter()
                result = robot.step(HOLD)
                times.append((time.perf_counter() - t) * 1e3)
                if result.terminated or result.truncated:
                    robot.reset()
            health = robot.health()
    finally:
        proc.terminate()
        proc.wait(10)
    t = np.array(times)
    return {"speed": speed, "period_ms": 100.0 / speed, "mean": t.mean(), "median": float(np.median(t)),
            "min": t.min(), "max": t.max(), "late_actions": health.late_actions, "overruns": health.overruns}


def render_times() -> dict:
    backend, reasons = find_gl_backend()
    if backend is None:
        return {"skipped": reasons}
    out = subprocess.run([sys.executable, "-c", _RENDER], env={**os.environ, "MUJOCO_GL": backend},
                         capture_output=True, text=True, check=True, timeout=600)
    return {"backend": backend, **json.loads(out.stdout.strip().splitlines()[-1])}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--out", default="bench/results/robots.json")
    args = p.parse_args()
    result = {
        "step_ms": [step_latency(1.0, 20), step_latency(20.0, 90)],
        "render_ms": render_times(),
        "experts": [evaluate_expert(task, arm, args.episodes) for task, arm in PAIRS],
    }
    print(json.dumps(result, indent=1, default=float))
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(result, f, indent=1, default=float)


if __name__ == "__main__":
    main()
