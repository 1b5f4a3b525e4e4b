"""SAC Flow: a flow-matching policy trained with the SAC objective (the paper's gated "Flow-G" variant).

Reference: Zhang et al. 2025, "SAC Flow: Sample-Efficient Reinforcement Learning of Flow-Based Policies
via Velocity-Reparameterized Sequential Modeling" (arXiv:2509.25756). Design choices:

* Actor: a velocity network ``[normalize(obs), a_k, onehot(k)] -> [candidate (A), gate logit (A)]`` and a
  noise-scale network ``normalize(obs) -> raw log_std (A)`` (bounded like SAC's). An action is K noisy
  Euler steps from ``a_0 ~ N(0, I)`` with the gated velocity ``sigmoid(g) * (c - a_k)``, then tanh
  (``core.flow``): the K-step rollout is a sequential model whose update is a GRU-like convex mix, so
  gradients through it stay bounded. The gate's output bias starts at ``gate_bias`` (open gates), the
  candidate's output layer small, as in the paper's code.
* Entropy: the rollout is a chain of K + 1 Gaussians whose log-densities sum (plus the tanh log-Jacobian):
  that log-probability replaces SAC's in the actor, critic-target and temperature losses, with automatic
  temperature toward ``target_entropy_per_dim * |A|``. The default per-dimension target is 0, as in the
  authors' public code (SAC's ``-|A|`` times 0), not SAC's -1: what is estimated is the entropy of the whole
  chain (the intermediate actions' Gaussians included), not the action's, so SAC's calibration of ``-|A|``
  does not carry over.
* Step times are a one-hot of the step index (the K steps are discrete), which also lets ``act`` read K
  from the published weights' shapes. Workers draw ``(MAX_FLOW_STEPS + 1) |A|`` standard normals per env
  step (``noise_dim``); a K-step actor reads the first ``(K + 1) |A|``.
* Critics, targets, update order, normalisation: SAC's (``sac.py``), run by the SAC-family learners.

Published weights: ``{"actor": {"velocity": mlp, "log_std": mlp}, "obs_norm": RunningStats}``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.algos.offpolicy import image_obs
from unilab_jax.algos.offpolicy.sac import (
    LOG_STD_MAX,
    LOG_STD_MIN,
    Norms,
    SACConfig,
    critic_input,
    discounts,
    ensemble_init,
    extras,
    mlp_apply,
    scalar_q,
    temperature_loss,
)
from unilab_jax.core import flow, normalizer
from unilab_jax.core import sac_losses as sac_core
from unilab_jax.lazy import learner_maker

SYNC = "async"
BUFFER = "replay"
IMAGES = True  # learns from image observations (``image_obs``)
MAX_FLOW_STEPS = 16

__all__ = ["SYNC", "BUFFER", "IMAGES", "Config", "SACFlowConfig", "extras", "act", "make_learner", "noise_dim",
           "init_params", "critic_loss", "actor_loss", "temperature_loss", "sample"]


@dataclasses.dataclass(frozen=True)
class SACFlowConfig(SACConfig):
    """SAC's fields plus the flow's: ``flow_steps`` (K Euler steps), ``gate_bias`` (initial gate logit); the
    entropy target per action dimension defaults to 0 (see the module's docstring)."""

    flow_steps: int = 4
    gate_bias: float = 5.0
    target_entropy_per_dim: float = 0.0

    def problems(self) -> list[str]:
        problems = super().problems()
        if not 1 <= self.flow_steps <= MAX_FLOW_STEPS:
            problems.append(f"flow_steps must be in [1, {MAX_FLOW_STEPS}], got {self.flow_steps}")
        return problems


Config = SACFlowConfig
make_learner = learner_maker(__name__)


def noise_dim(action_dim: int) -> int:
    """Standard normals a worker draws per env step (enough for the longest flow)."""
    return (MAX_FLOW_STEPS + 1) * action_dim


def learner_noise_dim(config: SACFlowConfig, action_dim: int) -> int:
    """Standard normals per sample the learner draws: ``a_0`` and one block per step."""
    return (config.flow_steps + 1) * action_dim


def init_params(key: Any, obs_dim: int, critic_obs_dim: int, action_dim: int, config: SACFlowConfig,
                xp: shim.Backend) -> dict[str, Any]:
    """``{"actor": {"velocity", "log_std"}, "critic": 2-ensemble [critic_obs + A -> 1]}``."""
    kv, ks, kc = xp.random.split(key, 3)
    return {"actor": actor_init(kv, ks, obs_dim, action_dim, config, xp),
            "critic": ensemble_init(kc, [critic_obs_dim + action_dim, *config.critic_hidden, 1], 2, xp)}


def actor_init(k_velocity: Any, k_log_std: Any, obs_dim: int, action_dim: int, config: SACFlowConfig,
               xp: shim.Backend) -> dict[str, Any]:
    """The flow actor ``{"velocity", "log_std"}``: gates open (``gate_bias``), small candidate outputs."""
    k, a = config.flow_steps, action_dim
    velocity = nets.init(k_velocity, [obs_dim + a + k, *config.actor_hidden, 2 * a], xp, final_scale=0.01)
    gate = xp.concat([xp.zeros((a,), dtype=xp.float32), xp.full((a,), config.gate_bias, dtype=xp.float32)])
    velocity[-1] = {**velocity[-1], "b": gate}
    return {"velocity": velocity,
            "log_std": nets.init(k_log_std, [obs_dim, *config.actor_hidden, a], xp, final_scale=0.01)}


def flow_steps(actor: dict, obs_dim: int, action_dim: int) -> int:
    """K, read from the velocity network's input width ``obs_dim + A + K``."""
    return int(actor["velocity"][0]["w"].shape[0]) - obs_dim - action_dim


def sample(actor: dict, obs_norm: normalizer.RunningStats, obs: Any, noise: Any,
           deterministic: bool = False) -> tuple[Any, Any]:
    """obs [B, D], noise [B, >= (K + 1) A] -> (action [B, A] in (-1, 1), log_prob [B]) by the gated chain."""
    xp = shim.namespace(obs)
    x = normalizer.normalize(obs_norm, obs)
    a_dim = int(actor["log_std"][-1]["w"].shape[-1])
    k_steps = flow_steps(actor, int(obs.shape[-1]), a_dim)
    raw = mlp_apply(actor["log_std"], x)
    log_std = LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (xp.tanh(raw) + 1.0)
    batch = tuple(obs.shape[:-1])
    step_codes = [xp.broadcast_to(xp.asarray([1.0 if j == k else 0.0 for j in range(k_steps)], dtype=xp.float32),
                                  (*batch, k_steps)) for k in range(k_steps)]

    def velocity(a: Any, k: int) -> Any:
        out = mlp_apply(actor["velocity"], xp.concat([x, a, step_codes[k]], axis=-1))
        return flow.gated_velocity(a, out[..., :a_dim], out[..., a_dim:])

    used = noise if deterministic else noise[..., :(k_steps + 1) * a_dim]
    pre, log_prob = flow.flow_rollout(velocity, used, log_std, k_steps, deterministic)
    return flow.squash(pre, log_prob)


def act(weights: dict, obs: Any, noise: Any, deterministic: bool = False, image: Any = None) -> tuple[Any, dict]:
    """obs [M, obs_dim], noise [M, noise_dim(A)] standard normal -> (action [M, A] in (-1, 1), {}).
    Deterministic: the noise-free rollout from ``a_0 = 0`` (``noise`` unread). Weights with an encoder need
    ``image`` (uint8 [M, H, W, C], as SAC's ``act``)."""
    xp = shim.namespace(obs)
    weights, obs = image_obs.actor_inputs(weights, obs, image)
    action, _ = sample(weights["actor"], weights["obs_norm"], obs, noise, deterministic)
    return xp.astype(action, xp.float32), {}


# ---------------------------------------------------------------------------------------------
# Losses: SAC's, with the chain's log-probability (``eps`` / ``eps_next`` are [B, (K + 1) A])
# ---------------------------------------------------------------------------------------------
def critic_loss(critic: Any, target_critic: Any, actor: Any, log_alpha: Any, norms: Norms, mb: dict,
                eps_next: Any, config: SACFlowConfig) -> tuple[Any, dict]:
    """Twin-critic MSE to ``r + gamma (1 - terminated) (min_i Q'_i(s', a') - alpha log pi(a'|s'))``,
    ``a'`` from the flow at ``next_obs``."""
    xp = shim.namespace(mb["reward"])
    next_action, next_log_prob = sample(actor, norms.obs, mb["next_obs"], eps_next)
    next_q = scalar_q(target_critic, critic_input(norms.critic, mb["next_critic_obs"], next_action))
    y = sac_core.sac_target(mb["reward"] / norms.reward_scale, discounts(mb, config.gamma), next_q[0], next_q[1],
                            next_log_prob, xp.exp(log_alpha))
    q = scalar_q(critic, critic_input(norms.critic, mb["critic_obs"], mb["action"]))
    loss = sac_core.sac_critic_loss(q[0], q[1], y)
    return loss, {"critic_loss": loss, "q_mean": xp.mean(q), "target_mean": xp.mean(y)}


def actor_loss(actor: Any, critic: Any, log_alpha: Any, norms: Norms, mb: dict, eps: Any,
               config: SACFlowConfig, use_min: bool = True) -> tuple[Any, tuple]:
    """``mean(alpha log pi(a|s) - min_i Q_i(s, a))`` through the K-step rollout (reparameterised); without
    ``use_min`` Q is the critic ensemble's mean instead (RLPD Flow)."""
    xp = shim.namespace(mb["obs"])
    action, log_prob = sample(actor, norms.obs, mb["obs"], eps)
    q = scalar_q(critic, critic_input(norms.critic, mb["critic_obs"], action))
    q1, q2 = (q[0], q[1]) if use_min else (xp.mean(q, axis=0),) * 2
    loss = sac_core.sac_actor_loss(q1, q2, log_prob, xp.exp(log_alpha))
    return loss, ({"actor_loss": loss, "entropy": -xp.mean(log_prob)}, log_prob)
