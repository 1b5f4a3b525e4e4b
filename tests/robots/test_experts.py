"""The scripted experts solve their tasks: 50 episodes per (task, arm), in-process, unpaced, no cameras."""

from __future__ import annotations

import json
import math
import time

import pytest

from unilab_jax.robots.experts import make_expert
from unilab_jax.robots.sim import SimConfig, SimRobot

EPISODES = 50
PAIRS = [("peg_insertion", "franka"), ("pick_place", "franka"), ("pick_place", "ur5e"), ("peg_insertion", "ur5e")]


def run_expert(task: str, arm: str, episodes: int, seed: int = 0) -> dict:
    """Success rate and mean episode length of the scripted expert on ``episodes`` random episodes."""
    robot = SimRobot(SimConfig(arm=arm, task=task, speed=math.inf, cameras=(), reset_seconds=0.0, seed=seed))
    expert = make_expert(robot.spec)
    successes, steps = 0, 0
    t = time.perf_counter()
    for episode in range(episodes):
        obs = robot.reset(seed=seed * 100_000 + episode)
        expert.reset()
        while True:
            result = robot.step(expert(obs))
            obs = result.obs
            if result.terminated or result.truncated:
                break
        successes += result.info["success"]
        steps += result.info["t"]
    return {"task": task, "arm": arm, "episodes": episodes, "success_rate": successes / episodes,
            "mean_steps": steps / episodes, "seconds": time.perf_counter() - t}


@pytest.mark.parametrize("task,arm", PAIRS)
def test_scripted_expert_success_rate(task, arm, tmp_path):
    stats = run_expert(task, arm, EPISODES)
    print(f"\nexpert {task} on {arm}: success {stats['success_rate']:.2f} over {EPISODES} episodes, "
          f"{stats['mean_steps']:.1f} steps/episode, {stats['seconds']:.1f} s")
    (tmp_path / f"expert_{task}_{arm}.json").write_text(json.dumps(stats, indent=1))
    assert stats["success_rate"] >= 0.9
