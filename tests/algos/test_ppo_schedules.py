"""PPO's schedules (``lr_schedule``, ``final_std`` over ``schedule_steps``) in the JAX learner: the learning rate
follows the schedule whatever the KL, the action std stays under its falling bound while an entropy bonus pushes it
up, and the config refuses schedules it cannot run. (The MLX learner's numbers: tests/mlx/test_ppo_parity.py.)"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compile_options import FAST_COMPILE

from tasks.base import TaskSpec
from unilab_jax import nets
from unilab_jax.algos.ppo import ppo
from unilab_jax.algos.ppo.learner_jax import Learner
from unilab_jax.config import ConfigError, apply_overrides

SPEC = TaskSpec(name="t", obs_dim=4, critic_obs_dim=5, action_dim=2, episode_length=50, ctrl_dt=0.02,
                reward_terms=("r",))
T, B = 4, 8  # 32 samples per update


def _batch(weights: dict, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    f32 = lambda x: np.asarray(x, np.float32)
    obs = f32(rng.normal(size=(T * B, SPEC.obs_dim)))
    action, ex = ppo.act(weights, obs, f32(rng.normal(size=(T * B, SPEC.action_dim))))
    batch = {"obs": obs, "critic_obs": f32(rng.normal(size=(T * B, SPEC.critic_obs_dim))), "action": f32(action),
             **{k: f32(v) for k, v in ex.items()}}
    batch = {k: v.reshape(T, B, *v.shape[1:]) for k, v in batch.items()}
    batch.update(next_critic_obs=batch["critic_obs"], reward=f32(rng.normal(size=(T, B))),
                 terminated=np.zeros((T, B), bool), truncated=np.zeros((T, B), bool))
    return {k: jnp.asarray(v) for k, v in batch.items()}


def _run(updates: int, **overrides) -> list[dict]:
    config = ppo.PPOConfig(actor_hidden=(16,), critic_hidden=(16,), num_epochs=2, num_minibatches=2, **overrides)
    learner = Learner(config, SPEC, compiler_options=FAST_COMPILE)
    state = learner.init(jax.random.PRNGKey(0))
    rows = []
    for i in range(updates):
        state, metrics = learner.update(state, _batch(nets.to_numpy(Learner.weights(state)), i))
        rows.append({**{k: float(v) for k, v in metrics.items()}, "std": np.exp(np.asarray(state.params["log_std"]))})
    return rows


def test_std_bound_and_learning_rate_follow_their_schedules():
    # 4 updates of 32 samples = 128 env steps: the std bound 1 -> 0.4 and the rate 1e-2 -> 2e-3, then held.
    # The entropy bonus pushes the std up, so it sits at the bound; learning_rate 1e-2 moves the policy far
    # beyond desired_kl, so the KL rule would have cut the rate.
    rows = _run(6, ent_coef=1.0, learning_rate=1e-2, desired_kl=1e-4, lr_schedule="linear",
                final_learning_rate=2e-3, final_std=0.4, schedule_steps=128)
    for i, row in enumerate(rows):
        fraction = min(i / 4, 1.0)  # the schedules' position during update i (i * 32 / 128)
        np.testing.assert_allclose(row["std"], 1.0 + (0.4 - 1.0) * fraction, rtol=1e-5)
        assert row["action_std"] == pytest.approx(1.0 + (0.4 - 1.0) * fraction, rel=1e-5)
        assert row["learning_rate"] == pytest.approx(1e-2 + (2e-3 - 1e-2) * fraction, rel=1e-5)
        assert row["kl"] > 2e-4


def test_fixed_learning_rate_ignores_the_kl_and_the_std_is_free_without_a_bound():
    rows = _run(2, ent_coef=1.0, learning_rate=1e-2, desired_kl=1e-4, lr_schedule="fixed")
    assert [r["learning_rate"] for r in rows] == pytest.approx([1e-2, 1e-2])
    assert rows[-1]["kl"] > 2e-4  # the KL rule would have divided the rate
    assert (rows[-1]["std"] > 1.01).all()  # the same bonus as above grows an unbounded std


@pytest.mark.parametrize("overrides, match", [
    ({"lr_schedule": "cosine"}, "lr_schedule must be one of"),
    ({"lr_schedule": "linear", "schedule_steps": 100}, "final_learning_rate"),
    ({"final_std": 0.3}, "schedule_steps must be positive"),
    ({"final_std": 2.0, "schedule_steps": 100}, "final_std must be"),
    ({"final_std": 0.3, "schedule_steps": 100, "init_log_std": math.log(0.2)}, "final_std must be"),
])
def test_bad_schedules_are_refused(overrides, match):
    with pytest.raises(ConfigError, match=match):
        apply_overrides(ppo.PPOConfig(), overrides)
