"""FastSAC: SAC for massively parallel simulation with C51 distributional twin critics.

References: Seo et al., "FastTD3: Simple, Fast, and Capable Reinforcement Learning for Humanoid
Control" (arXiv:2505.22642) and its SAC variant FastSAC (Seo et al. 2025, "Learning Sim-to-Real
Humanoid Locomotion in 15 Minutes"); C51 from Bellemare, Dabney & Munos, "A Distributional
Perspective on Reinforcement Learning" (ICML 2017). Design choices:

* Data regime: many parallel envs feed the replay ring; large batches (``batch_size`` 8192 by default,
  sized for a GPU: lower it on CPU) and several gradient steps per vectorised env step
  (``utd`` per collected transition: 8 steps per 1024 transitions by default).
* Critics: two C51 heads over a fixed support ``linspace(v_min, v_max, num_atoms)`` (101 atoms),
  one stacked ensemble, optional LayerNorm in the hidden layers (``critic_layer_norm``). The soft
  target distribution is ``r - gamma (1 - terminated) alpha log pi(a'|s') + gamma (1 - terminated) Z'``
  projected onto the support (the Cramer/L2 projection: ``core.c51.categorical_projection``, or with
  ``projection="prefix"`` ``categorical_projection_uniform``, the same in O(B K) work);
  ``Z'`` is the target critic whose mean is smaller (clipped double Q, ``use_cdq``; the choice is
  made before projecting, so only one projection per sample is computed) or the average of both.
  Loss: the sum of both critics' cross-entropies to that target.
* Actor: SAC's tanh-squashed Gaussian (``sac.act`` unchanged) maximising ``min_i E[Z_i]``
  (or the mean with ``use_cdq=False``) minus the entropy term; auto-temperature starting at a small
  ``init_alpha`` (FastSAC starts near-deterministic and lets the temperature rise if needed).
* Observation normalisation on by default; AdamW weight decay as in FastTD3; fast Polyak
  (``tau=0.1``) since the large batches make each step less noisy.
* ``v_min``/``v_max`` must bracket the task's discounted returns: set them per task.

Published weights are SAC's: ``{"actor": mlp, "obs_norm": RunningStats}``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.algos.offpolicy.sac import (
    Norms,
    SACConfig,
    act,
    critic_input,
    discounts,
    ensemble_init,
    extras,
    mlp_apply,
    policy,
    soft_actor_loss,
    temperature_loss,
)
from unilab_jax.core import c51, distributions
from unilab_jax.lazy import learner_maker

SYNC = "async"
BUFFER = "replay"

__all__ = ["SYNC", "BUFFER", "Config", "FastSACConfig", "extras", "act", "make_learner", "Norms",
           "actor_loss", "critic_loss", "categorical_target", "init_params", "temperature_loss"]


@dataclasses.dataclass(frozen=True)
class CategoricalSACConfig(SACConfig):
    """SAC for many parallel envs with C51 twin critics (FastSAC's and FlashSAC's common ground): large
    batches and replay, fast Polyak, the categorical support and clipped double Q."""

    batch_size: int = 8192
    replay_capacity: int = 2_097_152
    learning_starts: int = 16_384
    tau: float = 0.1
    num_atoms: int = 101
    v_min: float = -10.0
    v_max: float = 10.0
    use_cdq: bool = True
    # The target's projection onto the support: "dense" (``c51.categorical_projection``, a [B, K, K] weight) or
    # "prefix" (``c51.categorical_projection_uniform``: prefix sums, O(B K)); the same result up to float32 rounding.
    projection: str = "dense"

    def problems(self) -> list[str]:
        problems = super().problems()
        if self.num_atoms < 2 or not self.v_min < self.v_max:
            problems.append(f"need num_atoms >= 2 and v_min < v_max (got {self.num_atoms}, "
                            f"[{self.v_min}, {self.v_max}])")
        if self.projection not in ("dense", "prefix"):
            problems.append(f"projection must be 'dense' or 'prefix', got {self.projection!r}")
        return problems


@dataclasses.dataclass(frozen=True)
class FastSACConfig(CategoricalSACConfig):
    """FastSAC hyperparameters (FastTD3/FastSAC-style)."""

    actor_hidden: tuple[int, ...] = (512, 256, 128)
    critic_hidden: tuple[int, ...] = (1024, 512, 256)
    utd: float = 8.0 / 1024.0
    gamma: float = 0.97
    init_alpha: float = 0.001
    critic_layer_norm: bool = True
    weight_decay: float = 0.1


Config = FastSACConfig
make_learner = learner_maker(__name__)


def init_params(key: Any, obs_dim: int, critic_obs_dim: int, action_dim: int, config: FastSACConfig,
                xp: shim.Backend) -> dict[str, Any]:
    """``{"actor": mlp [obs -> 2A], "critic": 2-ensemble [critic_obs + A -> num_atoms] logits}``."""
    ka, kc = xp.random.split(key, 2)
    return {
        "actor": nets.init(ka, [obs_dim, *config.actor_hidden, 2 * action_dim], xp, final_scale=0.01),
        "critic": ensemble_init(kc, [critic_obs_dim + action_dim, *config.critic_hidden, config.num_atoms], 2, xp,
                                final_scale=0.01, layer_norm=config.critic_layer_norm),
    }


def support(config: Any, xp: shim.Backend) -> Any:
    """The fixed C51 support ``linspace(v_min, v_max, num_atoms)`` [K] (float32; ``c51.uniform_support``)."""
    return c51.uniform_support(config.v_min, config.v_max, config.num_atoms, xp)


def categorical_target(target_critic: Any, actor: Any, log_alpha: Any, norms: Norms, mb: dict, eps_next: Any,
                       config: Any, actor_apply: Callable = mlp_apply,
                       critic_apply: Callable = mlp_apply) -> Any:
    """Projected soft target distribution [B, K] (gradient-stopped).

    With ``d = gamma (1 - terminated)`` and ``a' = tanh(mean(s') + std(s') eps_next)``: the
    distribution of ``r / reward_scale - d alpha log pi(a'|s') + d Z'`` on ``support(config)``, where
    ``Z'`` is the target critic with the smaller mean (``config.use_cdq``) or the mixture of both.
    """
    xp = shim.namespace(mb["reward"])
    atoms = support(config, xp)
    mean, log_std = policy(actor, norms.obs, mb["next_obs"], actor_apply)
    next_action, next_log_prob = distributions.tanh_gaussian_sample(mean, log_std, eps_next)
    logits = critic_apply(target_critic, critic_input(norms.critic, mb["next_critic_obs"], next_action))
    probs = xp.softmax(logits, axis=-1)  # [2, B, K]
    if config.use_cdq:
        values = xp.sum(probs * atoms, axis=-1)  # [2, B]
        next_probs = xp.where((values[0] <= values[1])[:, None], probs[0], probs[1])
    else:
        next_probs = 0.5 * (probs[0] + probs[1])
    d = discounts(mb, config.gamma)
    shifted = mb["reward"] / norms.reward_scale - d * xp.exp(log_alpha) * next_log_prob
    if config.projection == "prefix":
        return c51.categorical_projection_uniform(xp.stop_gradient(next_probs), xp.stop_gradient(shifted), d,
                                                  v_min=config.v_min, v_max=config.v_max)
    return c51.categorical_projection(atoms, xp.stop_gradient(next_probs), xp.stop_gradient(shifted), d)


def categorical_critic_loss(critic: Any, target_critic: Any, actor: Any, log_alpha: Any, norms: Norms, mb: dict,
                            eps_next: Any, config: Any, actor_apply: Callable = mlp_apply,
                            critic_apply: Callable = mlp_apply) -> tuple[Any, dict]:
    """Sum over the two critics of the cross-entropy to ``categorical_target`` (scalar, metrics)."""
    xp = shim.namespace(mb["reward"])
    atoms = support(config, xp)
    target = categorical_target(target_critic, actor, log_alpha, norms, mb, eps_next, config, actor_apply,
                                critic_apply)
    logits = critic_apply(critic, critic_input(norms.critic, mb["critic_obs"], mb["action"]))  # [2, B, K]
    loss = c51.categorical_critic_loss(logits[0], target) + c51.categorical_critic_loss(logits[1], target)
    q = xp.sum(xp.softmax(logits, axis=-1) * atoms, axis=-1)
    return loss, {"critic_loss": loss, "q_mean": xp.mean(q), "target_mean": xp.mean(xp.sum(target * atoms, axis=-1))}


def categorical_q_fn(config: Any, critic_apply: Callable = mlp_apply) -> Callable:
    """``q_fn(critic, x) -> [E, B]``: the mean of each C51 critic."""

    def q_fn(critic: Any, x: Any) -> Any:
        logits = critic_apply(critic, x)
        xp = shim.namespace(logits)
        return c51.categorical_mean(logits, support(config, xp))

    return q_fn


def critic_loss(critic: Any, target_critic: Any, actor: Any, log_alpha: Any, norms: Norms, mb: dict,
                eps_next: Any, config: FastSACConfig) -> tuple[Any, dict]:
    """FastSAC critic loss: see ``categorical_critic_loss`` (MLP networks)."""
    return categorical_critic_loss(critic, target_critic, actor, log_alpha, norms, mb, eps_next, config)


def actor_loss(actor: Any, critic: Any, log_alpha: Any, norms: Norms, mb: dict, eps: Any,
               config: FastSACConfig) -> tuple[Any, tuple]:
    """``mean(alpha log pi - Q)`` with Q the C51 means (min over critics with ``use_cdq``)."""
    return soft_actor_loss(actor, critic, log_alpha, norms, mb, eps, categorical_q_fn(config),
                           use_min=config.use_cdq)
