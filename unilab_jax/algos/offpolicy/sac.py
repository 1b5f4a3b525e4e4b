"""SAC: soft actor-critic, asynchronous, on per-worker replay rings.

Reference: Haarnoja et al., "Soft Actor-Critic: Off-Policy Maximum Entropy Deep RL with a Stochastic
Actor" (ICML 2018, arXiv:1801.01290) and "Soft Actor-Critic Algorithms and Applications"
(arXiv:1812.05905, automatic temperature). Design choices:

* Actor: an MLP ``obs -> [mean, raw_log_std]`` (2A outputs), tanh-squashed Gaussian with the exact
  log-probability correction (``core.distributions.tanh_gaussian_sample``). ``log_std`` is bounded
  smoothly, ``LOG_STD_MIN + (LOG_STD_MAX - LOG_STD_MIN) * (tanh(raw) + 1) / 2`` (CleanRL / FastSAC),
  so it never saturates a hard clip with zero gradient.
* Twin critics ``Q_i(critic_obs, action)`` (asymmetric: the critic sees the privileged
  ``critic_obs``), stored as ONE stacked ensemble pytree (weights ``[2, in, out]``, vectors
  ``[2, 1, out]``) so both run as one batched matmul; ``nets.apply`` works on it unchanged.
* Soft Bellman target ``r + gamma (1 - terminated) (min_i Q'_i(s', a') - alpha log pi(a'|s'))`` with
  ``a' ~ pi(.|s')`` from the current actor and Polyak-averaged target critics (``tau``). Truncated
  transitions bootstrap from ``next_obs`` (the true successor, before auto-reset).
* Update order per gradient step (CleanRL / Haarnoja): critics, then the actor against the freshly
  updated critics, then the temperature ``log_alpha`` against the target entropy
  ``target_entropy_per_dim * |A|`` (default ``-|A|``), then Polyak.
* Observation normalisation (``normalize_obs``): running mean/var of ``obs`` (published to the
  workers with the actor) and of ``critic_obs`` (learner only), updated from the first of the U
  minibatches of every ``update`` call, so the count tracks sampled data rather than U x B.

Images (``spec.image_shape``, ``image_obs``): a DrQ encoder in the critic's parameters, its features appended
to the actor's and critic's observations; ``encoder_*``, ``feature_dim`` and ``image_pad`` configure it.

Published weights: ``{"actor": mlp, "obs_norm": RunningStats}`` (with images also ``encoder``,
``encoder_strides``). The pure loss functions below are
written against the shim (numpy / jax / mlx); the learners are ``learner_jax`` and ``learner_mlx`` beside it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.algos.offpolicy import image_obs
from unilab_jax.algos.offpolicy.base_config import OffPolicyConfig
from unilab_jax.algos.offpolicy.shared import (  # re-exported: the family's declarations import them from here
    Norms,
    critic_input,
    discounts,
    ensemble_init,
    mlp_apply,
    scalar_q,
)
from unilab_jax.core import distributions, normalizer
from unilab_jax.core import sac_losses as sac_core
from unilab_jax.lazy import learner_maker

SYNC = "async"
BUFFER = "replay"
LOG_STD_MIN = -5.0
LOG_STD_MAX = 2.0
IMAGES = True  # learns from image observations (``image_obs``)


@dataclasses.dataclass(frozen=True)
class SACConfig(OffPolicyConfig):
    """SAC hyperparameters (Haarnoja et al. / CleanRL defaults, sized for many parallel envs): the
    off-policy fields plus the temperature's."""

    alpha_learning_rate: float = 3e-4
    init_alpha: float = 0.2
    autotune_alpha: bool = True
    target_entropy_per_dim: float = -1.0  # target entropy = this * action_dim
    # Image encoder (read only for tasks with ``spec.image_shape``; SAC, RLPD, SAC Flow): 3x3 convolutions of
    # ``encoder_channels`` with ``encoder_strides`` (one per convolution), a linear layer to ``feature_dim``
    # features (LayerNorm, tanh), and DrQ random shifts of up to ``image_pad`` pixels (0: no augmentation).
    encoder_channels: tuple[int, ...] = (32, 32, 32, 32)
    encoder_strides: tuple[int, ...] = (2, 1, 1, 1)
    feature_dim: int = 50
    image_pad: int = 4
    # The actor gets its own encoder, trained by the actor loss (``image_obs``): for an asymmetric actor-critic
    # whose critic also reads privileged state (the robot tasks' ``critic_state``), whose encoder need not learn
    # what the actor must see. False: the actor reads the critic encoder's features, gradient-stopped (DrQ).
    actor_encoder: bool = False

    def problems(self) -> list[str]:
        problems = super().problems()
        if self.init_alpha <= 0:
            problems.append("init_alpha must be positive")
        return problems + image_obs.check_config(self)


Config = SACConfig
make_learner = learner_maker(__name__)


def extras(action_dim: int) -> dict[str, tuple[tuple[int, ...], str]]:
    """SAC writes nothing per transition besides the task's fields."""
    return {}


# ---------------------------------------------------------------------------------------------
# Networks
# ---------------------------------------------------------------------------------------------
class SACState(NamedTuple):
    """Training state of SAC, FastSAC and FlashSAC (one pytree; arrays of the learner's platform)."""

    actor: Any
    critic: Any  # twin critics, stacked ensemble (leading axis 2)
    target_critic: Any
    actor_opt: Any
    critic_opt: Any
    log_alpha: Any  # [] float32
    alpha_opt: Any
    obs_norm: normalizer.RunningStats
    critic_norm: normalizer.RunningStats
    reward_norm: normalizer.RunningStats  # D = 1: reward moments (FlashSAC reward normalisation; unused by SAC)
    key: Any
    steps: Any  # gradient steps so far (int32)


def tanh_gaussian_head(out: Any) -> tuple[Any, Any]:
    """Splits an actor output ``[..., 2A]`` into ``mean [..., A]`` and bounded ``log_std [..., A]``."""
    xp = shim.namespace(out)
    a = int(out.shape[-1]) // 2
    mean, raw = out[..., :a], out[..., a:]
    log_std = LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (xp.tanh(raw) + 1.0)
    return mean, log_std


def policy(actor: Any, obs_norm: normalizer.RunningStats, obs: Any,
           actor_apply: Callable = mlp_apply) -> tuple[Any, Any]:
    """Pre-squash Gaussian of the policy. obs [B, D] -> (mean [B, A], log_std [B, A])."""
    return tanh_gaussian_head(actor_apply(actor, normalizer.normalize(obs_norm, obs)))


def tanh_gaussian_act(weights: dict, obs: Any, noise: Any, deterministic: bool,
                      actor_apply: Callable = mlp_apply) -> tuple[Any, dict]:
    """Worker-side tanh-Gaussian policy: ``tanh(mean)`` or ``tanh(mean + std * noise)``."""
    xp = shim.namespace(obs)
    mean, log_std = policy(weights["actor"], weights["obs_norm"], obs, actor_apply)
    u = mean if deterministic else mean + xp.exp(log_std) * noise
    return xp.astype(xp.tanh(u), xp.float32), {}


def act(weights: dict, obs: Any, noise: Any, deterministic: bool = False, image: Any = None) -> tuple[Any, dict]:
    """obs [M, obs_dim], noise [M, A] standard normal -> (action [M, A] in (-1, 1), {}); weights with an
    encoder need ``image`` (uint8 [M, H, W, C]), whose features widen ``obs``."""
    weights, obs = image_obs.actor_inputs(weights, obs, image)
    return tanh_gaussian_act(weights, obs, noise, deterministic)


def init_params(key: Any, obs_dim: int, critic_obs_dim: int, action_dim: int, config: SACConfig,
                xp: shim.Backend) -> dict[str, Any]:
    """``{"actor": mlp [obs -> 2A], "critic": 2-ensemble [critic_obs + A -> 1]}``."""
    ka, kc = xp.random.split(key, 2)
    return {
        "actor": nets.init(ka, [obs_dim, *config.actor_hidden, 2 * action_dim], xp, final_scale=0.01),
        "critic": ensemble_init(kc, [critic_obs_dim + action_dim, *config.critic_hidden, 1], 2, xp),
    }


def policy_weights(actor: Any, obs_norm: normalizer.RunningStats) -> dict[str, Any]:
    """The published weight pytree ``act`` reads."""
    return {"actor": actor, "obs_norm": obs_norm}


# ---------------------------------------------------------------------------------------------
# Losses (pure; every batch field is [B, ...]: obs, critic_obs, action, reward, next_obs,
# next_critic_obs, terminated, truncated as float32)
# ---------------------------------------------------------------------------------------------
def critic_target(target_critic: Any, actor: Any, log_alpha: Any, norms: Norms, mb: dict, eps_next: Any,
                  gamma: float) -> Any:
    """Soft Bellman target [B] (gradient-stopped).

    ``y = r / reward_scale + gamma (1 - terminated) (min_i Q'_i(s', a') - alpha log pi(a'|s'))`` with
    ``a' = tanh(mean(s') + std(s') * eps_next)``; eps_next: [B, A] standard normal.
    """
    xp = shim.namespace(mb["reward"])
    mean, log_std = policy(actor, norms.obs, mb["next_obs"])
    next_action, next_log_prob = distributions.tanh_gaussian_sample(mean, log_std, eps_next)
    next_q = scalar_q(target_critic, critic_input(norms.critic, mb["next_critic_obs"], next_action))
    alpha = xp.exp(log_alpha)
    return sac_core.sac_target(mb["reward"] / norms.reward_scale, discounts(mb, gamma), next_q[0], next_q[1],
                               next_log_prob, alpha)


def critic_loss(critic: Any, target_critic: Any, actor: Any, log_alpha: Any, norms: Norms, mb: dict,
                eps_next: Any, config: SACConfig) -> tuple[Any, dict]:
    """Twin-critic MSE to the soft target (scalar; gradients reach ``critic`` only)."""
    xp = shim.namespace(mb["reward"])
    y = critic_target(target_critic, actor, log_alpha, norms, mb, eps_next, config.gamma)
    q = scalar_q(critic, critic_input(norms.critic, mb["critic_obs"], mb["action"]))
    loss = sac_core.sac_critic_loss(q[0], q[1], y)
    return loss, {"critic_loss": loss, "q_mean": xp.mean(q), "target_mean": xp.mean(y)}


def soft_actor_loss(actor: Any, critic: Any, log_alpha: Any, norms: Norms, mb: dict, eps: Any,
                    q_fn: Callable, actor_apply: Callable = mlp_apply, use_min: bool = True) -> tuple[Any, tuple]:
    """``mean(alpha log pi(a|s) - Q(s, a))``, ``a = tanh(mean + std * eps)`` reparameterised.

    ``q_fn(critic, x [B, Dc + A]) -> [E, B]``; Q is the min over the ensemble (``use_min``) or its
    mean. Returns ``(loss, (metrics, log_prob [B]))``; the log probs feed the temperature loss.
    """
    xp = shim.namespace(mb["obs"])
    mean, log_std = policy(actor, norms.obs, mb["obs"], actor_apply)
    action, log_prob = distributions.tanh_gaussian_sample(mean, log_std, eps)
    q = q_fn(critic, critic_input(norms.critic, mb["critic_obs"], action))
    if not use_min:
        q = xp.stack([xp.mean(q, axis=0)] * 2)
    loss = sac_core.sac_actor_loss(q[0], q[1], log_prob, xp.exp(log_alpha))
    return loss, ({"actor_loss": loss, "entropy": -xp.mean(log_prob),
                   "policy_std": xp.mean(xp.exp(log_std))}, log_prob)


def actor_loss(actor: Any, critic: Any, log_alpha: Any, norms: Norms, mb: dict, eps: Any,
               config: SACConfig) -> tuple[Any, tuple]:
    """SAC actor loss with twin scalar critics (min); see ``soft_actor_loss``."""
    return soft_actor_loss(actor, critic, log_alpha, norms, mb, eps, scalar_q)


def temperature_loss(log_alpha: Any, log_prob: Any, target_entropy: float) -> Any:
    """``-mean(alpha (log pi + target_entropy))`` (log probs gradient-stopped). log_prob: [B]."""
    return sac_core.sac_temperature_loss(log_alpha, log_prob, target_entropy)
