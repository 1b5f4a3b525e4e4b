"""RLPD: SAC with prior data (Ball, Smith, Kostrikov & Levine, "Efficient Online Reinforcement Learning
with Offline Data", ICML 2023, arXiv:2302.02948). Design choices (the paper's):

* Symmetric sampling: each minibatch is half online transitions (the replay rings) and half prior data
  (``prior_dir``: a replay store, e.g. recorded demonstrations, ``python -m unilab_jax.robots.record``),
  ``prior_fraction`` of it; the trainer composes it (``core.rlpd.compose``). No offline pretraining:
  the learner starts from scratch with the online data.
* A critic ensemble of ``num_critics`` (10) members with LayerNorm in the hidden layers
  (``critic_layer_norm``), one stacked ensemble pytree; the soft target takes the minimum over a random
  subset of ``subset_size`` (2) target members, redrawn every gradient step (``core.rlpd``); the loss is
  the mean squared error over all members.
* The actor maximises the ensemble's mean Q minus the entropy term (SAC's tanh-Gaussian, ``sac.act``);
  automatic temperature; a high update-to-data ratio (``utd``, 20 in the paper for sample efficiency), with
  the actor and temperature moved on every ``actor_every``-th gradient step only (the paper's code moves
  them once per ``utd`` critic steps; the default 1 moves them every step).

The SAC family learners run it (``learner_jax`` / ``learner_mlx``): ``critic_noise_shape`` asks them for a
uniform ``[num_critics]`` draw per gradient step next to ``eps_next`` (``critic_loss`` gets both).
Published weights are SAC's. RLPD Flow (``rlpdflow.py``) is this with SAC Flow's actor: ``critic_target`` and
``critic_loss`` take the policy's draw (``sample``) as an argument.
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
    policy,
    scalar_q,
    soft_actor_loss,
    temperature_loss,
)
from unilab_jax.core import distributions
from unilab_jax.core import rlpd_kernels as rlpd
from unilab_jax.core import sac_losses as sac_core
from unilab_jax.lazy import learner_maker

SYNC = "async"
BUFFER = "replay"
IMAGES = True  # learns from image observations (``image_obs``)
PRIOR_DATA = True  # Config.prior_dir / prior_fraction: the trainer mixes prior data into every minibatch

__all__ = ["SYNC", "BUFFER", "IMAGES", "PRIOR_DATA", "Config", "RLPDConfig", "extras", "act", "make_learner", "Norms",
           "actor_loss", "critic_loss", "critic_noise_shape", "actor_every", "init_params", "temperature_loss"]


@dataclasses.dataclass(frozen=True)
class RLPDConfig(SACConfig):
    """RLPD hyperparameters (the paper's defaults; ``utd`` is gradient steps per collected transition)."""

    batch_size: int = 256
    utd: float = 20.0
    learning_starts: int = 1_000
    init_alpha: float = 1.0
    target_entropy_per_dim: float = -0.5
    num_critics: int = 10
    subset_size: int = 2
    actor_every: int = 1  # critic steps per actor (and temperature) step; the paper's code: one per utd critic steps
    critic_layer_norm: bool = True
    prior_dir: str = ""  # replay store of prior data (demonstrations); "" trains on online data only (SAC + ensemble)
    prior_fraction: float = 0.5  # share of each minibatch from the prior data (0.5: symmetric sampling)

    def problems(self) -> list[str]:
        problems = super().problems()
        if not 1 <= self.subset_size <= self.num_critics:
            problems.append(f"need 1 <= subset_size <= num_critics (got {self.subset_size}, {self.num_critics})")
        if self.actor_every < 1:
            problems.append(f"actor_every must be >= 1, got {self.actor_every}")
        if not 0.0 <= self.prior_fraction < 1.0:
            problems.append(f"prior_fraction must be in [0, 1), got {self.prior_fraction}")
        return problems


Config = RLPDConfig
make_learner = learner_maker(__name__)


def critic_noise_shape(config: RLPDConfig) -> tuple[int, ...]:
    """Shape of the per-step uniform draw the learners pass to ``critic_loss`` (the subset's noise)."""
    return (config.num_critics,)


def actor_every(config: RLPDConfig) -> int:
    """Critic steps per actor (and temperature) step: ``config.actor_every``."""
    return config.actor_every


def init_params(key: Any, obs_dim: int, critic_obs_dim: int, action_dim: int, config: RLPDConfig,
                xp: shim.Backend) -> dict[str, Any]:
    """``{"actor": mlp [obs -> 2A], "critic": num_critics-ensemble [critic_obs + A -> 1] with LayerNorm}``."""
    ka, kc = xp.random.split(key, 2)
    return {
        "actor": nets.init(ka, [obs_dim, *config.actor_hidden, 2 * action_dim], xp, final_scale=0.01),
        "critic": critic_init(kc, critic_obs_dim, action_dim, config, xp),
    }


def critic_init(key: Any, critic_obs_dim: int, action_dim: int, config: RLPDConfig, xp: shim.Backend) -> Any:
    """The ``num_critics``-ensemble ``[critic_obs + A -> 1]``; LayerNorm in its hidden layers: ``critic_layer_norm``."""
    return ensemble_init(key, [critic_obs_dim + action_dim, *config.critic_hidden, 1], config.num_critics, xp,
                         layer_norm=config.critic_layer_norm)


def gaussian_sample(actor: Any, obs_norm: Any, obs: Any, eps: Any) -> tuple[Any, Any]:
    """SAC's tanh-Gaussian draw at ``obs``: (action [B, A], log_prob [B]); eps [B, A] standard normal."""
    mean, log_std = policy(actor, obs_norm, obs)
    return distributions.tanh_gaussian_sample(mean, log_std, eps)


def critic_target(target_critic: Any, actor: Any, log_alpha: Any, norms: Norms, mb: dict, eps_next: Any, u: Any,
                  config: RLPDConfig, sample: Callable = gaussian_sample) -> Any:
    """Soft target [B]: ``r + gamma (1 - terminated) (min_{e in S} Q'_e(s', a') - alpha log pi(a'|s'))``,
    ``S`` the ``subset_size`` members with the smallest ``u`` [E]; ``a'`` and ``log pi(a'|s')`` from
    ``sample(actor, obs_norm, next_obs, eps_next)`` (SAC's tanh-Gaussian; RLPD Flow: the flow's chain)."""
    xp = shim.namespace(mb["reward"])
    next_action, next_log_prob = sample(actor, norms.obs, mb["next_obs"], eps_next)
    subset = rlpd.ensemble_members(target_critic, rlpd.subset_indices(u, config.subset_size))
    q_min = xp.min(scalar_q(subset, critic_input(norms.critic, mb["next_critic_obs"], next_action)), axis=0)
    return sac_core.sac_target(mb["reward"] / norms.reward_scale, discounts(mb, config.gamma), q_min, q_min,
                               next_log_prob, xp.exp(log_alpha))


def critic_loss(critic: Any, target_critic: Any, actor: Any, log_alpha: Any, norms: Norms, mb: dict,
                noise: tuple[Any, Any], config: RLPDConfig, sample: Callable = gaussian_sample) -> tuple[Any, dict]:
    """Ensemble MSE to the subset-min soft target; ``noise = (eps_next [B, A], u [E])`` (``sample``: the policy's
    draw of the next action, as ``critic_target``'s)."""
    xp = shim.namespace(mb["reward"])
    eps_next, u = noise
    y = critic_target(target_critic, actor, log_alpha, norms, mb, eps_next, u, config, sample)
    q = scalar_q(critic, critic_input(norms.critic, mb["critic_obs"], mb["action"]))
    loss = rlpd.ensemble_critic_loss(q, y)
    return loss, {"critic_loss": loss, "q_mean": xp.mean(q), "q_std": xp.mean(xp.std(q, axis=0)),
                  "target_mean": xp.mean(y)}


def actor_loss(actor: Any, critic: Any, log_alpha: Any, norms: Norms, mb: dict, eps: Any,
               config: RLPDConfig) -> tuple[Any, tuple]:
    """SAC's actor loss against the ensemble's mean Q."""
    return soft_actor_loss(actor, critic, log_alpha, norms, mb, eps, scalar_q, use_min=False)
