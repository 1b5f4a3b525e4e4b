"""The scripted experts solve their tasks: 50 episodes per (task, arm), in-process, unpaced, no cameras; the
pick-and-place expert's descent starts wherever it is aligned over the cube."""

from __future__ import annotations

import json

import numpy as np
import pytest

from unilab_jax.robots.experts import OPEN, PAIRS, PickPlaceExpert, evaluate_expert, grasp_quat
from unilab_jax.robots.interface import RobotSpec

EPISODES = 50


@pytest.mark.parametrize("task,arm", PAIRS)
def test_scripted_expert_success_rate(task, arm, tmp_path):
    stats = evaluate_expert(task, arm, EPISODES)
    print(f"\nexpert {task} on {arm}: success {stats['success_rate']:.2f} over {EPISODES} episodes, "
          f"{stats['mean_steps']:.1f} steps/episode, {stats['seconds']:.1f} s")
    (tmp_path / f"expert_{task}_{arm}.json").write_text(json.dumps(stats, indent=1))
    assert stats["success_rate"] >= 0.9


def test_pick_place_expert_descends_once_aligned_over_the_cube_at_any_height():
    """Aligned over the cube in the plane and in yaw, the expert descends from where it is: below the point
    10 cm above the cube too (a switch at that point made its approach pull up there while its descent pushed
    down, and cloned policies stalled between them). Not yet aligned, it approaches that point first."""
    spec = RobotSpec(name="r", kind="franka", task="pick_place", proprio_dim=13, privileged_dim=18, cameras=(),
                     image_shape=(64, 64, 3), control_hz=10.0, episode_length=100, max_delta_pos=0.03,
                     max_delta_rot=0.25)
    cube = np.array([0.5, 0.05, 0.02])

    def obs(tcp):
        p = np.concatenate([tcp, grasp_quat(0.0), [1.0], cube, [1.0, 0.0, 0.0, 0.0], [0.48, -0.23, 0.0]])
        return {"privileged": p.astype(np.float32), "proprio": np.zeros(13, np.float32)}

    aligned = PickPlaceExpert(spec)
    action = aligned(obs(cube + [0.004, -0.003, 0.06]))
    assert aligned.phase == "descend" and action[2] < -0.5 and action[6] == OPEN
    beside = PickPlaceExpert(spec)
    action = beside(obs(cube + [0.03, 0.0, 0.06]))
    assert beside.phase == "approach" and action[2] > 0.5 and action[0] < -0.5 and action[6] == OPEN
