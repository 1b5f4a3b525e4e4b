"""The scripted experts solve their tasks: 50 episodes per (task, arm), in-process, unpaced, no cameras."""

from __future__ import annotations

import json

import pytest

from unilab_jax.robots.experts import PAIRS, evaluate_expert

EPISODES = 50


@pytest.mark.parametrize("task,arm", PAIRS)
def test_scripted_expert_success_rate(task, arm, tmp_path):
    stats = evaluate_expert(task, arm, EPISODES)
    print(f"\nexpert {task} on {arm}: success {stats['success_rate']:.2f} over {EPISODES} episodes, "
          f"{stats['mean_steps']:.1f} steps/episode, {stats['seconds']:.1f} s")
    (tmp_path / f"expert_{task}_{arm}.json").write_text(json.dumps(stats, indent=1))
    assert stats["success_rate"] >= 0.9
