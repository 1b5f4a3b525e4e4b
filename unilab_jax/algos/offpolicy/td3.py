"""TD3: twin delayed DDPG, asynchronous, on per-worker replay rings.

Reference: Fujimoto, van Hoof & Meger, "Addressing Function Approximation Error in Actor-Critic
Methods" (ICML 2018, arXiv:1802.09477). Design choices:

* Deterministic actor ``mu(s) = tanh(mlp(normalize(obs)))``. Exploration happens in the workers'
  ``act``: ``clip(mu(s) + explore_std * noise, -1, 1)`` with the worker's standard-normal noise.
  ``explore_std`` travels in the published weights (``act`` sees no config), which also leaves room
  for a learner-side schedule.
* Target policy smoothing: ``a' = clip(mu'(s') + clip(policy_noise * eps, +-noise_clip), -1, 1)``
  from the target actor; clipped double-Q target ``r + gamma (1 - terminated) min_i Q'_i(s', a')``
  (truncation bootstraps from ``next_obs``).
* Twin critics as one stacked ensemble (see ``sac.ensemble_init``); the actor maximises ``Q_1``.
* Delayed updates: the actor and BOTH target networks (Polyak, ``tau``) move every ``policy_delay``
  gradient steps (``jax.lax.cond`` inside the scanned update).
* Observation normalisation as in ``sac`` (``obs`` stats published, ``critic_obs`` stats learner-only).

Published weights: ``{"actor": mlp, "obs_norm": RunningStats, "explore_std": []}``.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.algos.offpolicy.base_config import OffPolicyConfig
from unilab_jax.algos.offpolicy.shared import ACTIVATION, Norms, critic_input, discounts, ensemble_init, mlp_apply
from unilab_jax.core import normalizer
from unilab_jax.core import td3_losses as td3_core
from unilab_jax.lazy import learner_maker

SYNC = "async"
BUFFER = "replay"

__all__ = ["SYNC", "BUFFER", "ACTIVATION", "Config", "TD3Config", "extras", "act", "make_learner",
           "actor_loss", "critic_loss", "critic_target", "init_params", "Norms"]


@dataclasses.dataclass(frozen=True)
class TD3Config(OffPolicyConfig):
    """TD3 hyperparameters (Fujimoto et al. defaults): the off-policy fields (``base_config.OffPolicyConfig``)
    plus exploration, target smoothing and the policy delay."""

    explore_std: float = 0.1  # std of the exploration noise added in the workers
    policy_noise: float = 0.2  # std of the target policy smoothing noise
    noise_clip: float = 0.5
    policy_delay: int = 2  # critic steps per actor (and target) step

    def problems(self) -> list[str]:
        problems = super().problems()
        if self.policy_delay < 1:
            problems.append("policy_delay must be >= 1")
        return problems


Config = TD3Config
make_learner = learner_maker(__name__)


def extras(action_dim: int) -> dict[str, tuple[tuple[int, ...], str]]:
    """TD3 writes nothing per transition besides the task's fields."""
    return {}


class TD3State(NamedTuple):
    """Training state of TD3 (one pytree; arrays of the learner's platform)."""

    actor: Any
    critic: Any
    target_actor: Any
    target_critic: Any
    actor_opt: Any
    critic_opt: Any
    obs_norm: normalizer.RunningStats
    critic_norm: normalizer.RunningStats
    explore_std: Any  # [] float32, published to the workers
    key: Any
    steps: Any


def init_params(key: Any, obs_dim: int, critic_obs_dim: int, action_dim: int, config: TD3Config,
                xp: shim.Backend) -> dict[str, Any]:
    """``{"actor": mlp [obs -> A], "critic": 2-ensemble [critic_obs + A -> 1]}``."""
    ka, kc = xp.random.split(key, 2)
    return {
        "actor": nets.init(ka, [obs_dim, *config.actor_hidden, action_dim], xp, final_scale=0.01),
        "critic": ensemble_init(kc, [critic_obs_dim + action_dim, *config.critic_hidden, 1], 2, xp),
    }


def policy_mean(actor: Any, obs_norm: normalizer.RunningStats, obs: Any) -> Any:
    """Deterministic action ``tanh(mlp(normalize(obs)))``: [B, D] -> [B, A]."""
    xp = shim.namespace(obs)
    return xp.tanh(mlp_apply(actor, normalizer.normalize(obs_norm, obs)))


def act(weights: dict, obs: Any, noise: Any, deterministic: bool = False) -> tuple[Any, dict]:
    """obs [M, obs_dim], noise [M, A] -> (``clip(mu + explore_std * noise, -1, 1)`` [M, A], {})."""
    xp = shim.namespace(obs)
    action = policy_mean(weights["actor"], weights["obs_norm"], obs)
    if not deterministic:
        action = xp.clip(action + weights["explore_std"] * noise, -1.0, 1.0)
    return xp.astype(action, xp.float32), {}


def critic_target(target_actor: Any, target_critic: Any, norms: Norms, mb: dict, eps_next: Any,
                  config: TD3Config) -> Any:
    """Clipped double-Q target with target policy smoothing, [B] (gradient-stopped).

    eps_next: [B, A] standard normal (scaled by ``policy_noise`` here, then clipped).
    """
    next_mean = policy_mean(target_actor, norms.obs, mb["next_obs"])
    next_action = td3_core.td3_target_action(next_mean, config.policy_noise * eps_next, config.noise_clip)
    next_q = mlp_apply(target_critic, critic_input(norms.critic, mb["next_critic_obs"], next_action))[..., 0]
    return td3_core.td3_target(mb["reward"] / norms.reward_scale, discounts(mb, config.gamma), next_q[0], next_q[1])


def critic_loss(critic: Any, target_actor: Any, target_critic: Any, norms: Norms, mb: dict, eps_next: Any,
                config: TD3Config) -> tuple[Any, dict]:
    """``mean((Q1 - y)^2) + mean((Q2 - y)^2)``; returns (scalar, metrics)."""
    xp = shim.namespace(mb["reward"])
    y = critic_target(target_actor, target_critic, norms, mb, eps_next, config)
    q = mlp_apply(critic, critic_input(norms.critic, mb["critic_obs"], mb["action"]))[..., 0]
    loss = td3_core.td3_critic_loss(q[0], q[1], y)
    return loss, {"critic_loss": loss, "q_mean": xp.mean(q), "target_mean": xp.mean(y)}


def actor_loss(actor: Any, critic: Any, norms: Norms, mb: dict) -> tuple[Any, dict]:
    """Deterministic policy gradient ``-mean(Q_1(s, mu(s)))``; returns (scalar, metrics)."""
    action = policy_mean(actor, norms.obs, mb["obs"])
    q = mlp_apply(critic, critic_input(norms.critic, mb["critic_obs"], action))[..., 0]
    loss = td3_core.td3_actor_loss(q[0])
    return loss, {"actor_loss": loss}
