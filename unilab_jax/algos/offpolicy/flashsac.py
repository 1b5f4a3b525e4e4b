"""FlashSAC: SAC with norm-bounded networks, a categorical critic on normalised rewards, and
exploration noise held for several steps.

Reference: "FlashSAC: Fast and Stable Off-Policy Reinforcement Learning for High-Dimensional Robot
Control" (arXiv:2604.04539): fewer gradient updates, larger models and more data per update, kept
stable by bounding weight, feature and gradient norms; related to SimbaV2 (Lee et al. 2025,
hyperspherical normalisation + distributional critic with reward scaling). Our reading, and where
this build deviates:

* Norm-bounded networks (actor and critics): the input gets a constant feature 1 appended (SimbaV2's
  shift: a bias inside the norm-bounded first matrix, without which ``rmsnorm(x @ W)`` would not
  see the input's magnitude); every hidden layer is ``z = relu(g * rmsnorm(h @ W) + o)``, with a
  residual ``h + z`` where the width is unchanged, then
  ``rmsnorm`` on the last features and a head ``(h @ W_out) * s + b``. After every optimizer step
  each weight matrix is projected so that every output unit's weight vector (each column of
  ``W [in, out]``) has unit L2 norm (``project_params``); the target critic is projected after its
  Polyak step too. The learnable gains ``g``/``s`` carry the scale the unit-norm weights cannot.
  Gradient norms are clipped (``max_grad_norm``). Deviation: the paper uses BatchNorm inside
  inverted residual blocks; we use RMSNorm, which is per-sample, so the numpy workers compute
  exactly the learner's function without publishing batch statistics.
* Critic: two C51 heads (``fastsac.categorical_critic_loss``) on a support ``[v_min, v_max]``
  chosen for NORMALISED returns. Reward normalisation: the learner keeps running statistics of
  sampled rewards and divides rewards by ``reward_scale = rms(r) / (1 - gamma)`` (the size of a
  discounted return of rewards of rms size) before the critic target, so normalised returns are
  O(1) on every task and a fixed support ``[-5, 5]`` fits all of them. (The paper keeps a running
  scale of discounted returns; the replay learner only sees shuffled transitions, so the return
  scale is estimated from the reward moments instead.) The temperature then acts on the normalised
  reward scale, which makes ``init_alpha`` and the entropy target task-independent.
* Exploration noise held for ``NOISE_HOLD_STEPS`` control steps (the runtime redraws the worker's
  standard-normal noise only every n steps): temporally correlated exploration that moves a legged
  robot further than white noise. n = 4 is our default, not a number from the paper.
* Fewer, larger updates: low ``utd``, large batches, fast Polyak.

Published weights: ``{"actor": flash net, "obs_norm": RunningStats}``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from unilab_jax import xp as shim
from unilab_jax.algos.offpolicy.fastsac import (
    CategoricalSACConfig,
    categorical_critic_loss,
    categorical_q_fn,
    categorical_target,
    support,
)
from unilab_jax.algos.offpolicy.sac import (
    Norms,
    extras,
    soft_actor_loss,
    tanh_gaussian_act,
    temperature_loss,
)
from unilab_jax.core import normalizer
from unilab_jax.lazy import learner_maker

SYNC = "async"
BUFFER = "replay"
NOISE_HOLD_STEPS = 4  # control steps each exploration-noise draw is held (read by the runtime)
_EPS = 1e-6

__all__ = ["SYNC", "BUFFER", "NOISE_HOLD_STEPS", "Config", "FlashSACConfig", "extras", "act", "make_learner",
           "Norms", "actor_loss", "critic_loss", "categorical_target", "init_params", "project_params",
           "reward_scale", "flash_init", "flash_apply", "support", "temperature_loss"]


@dataclasses.dataclass(frozen=True)
class FlashSACConfig(CategoricalSACConfig):
    """FlashSAC hyperparameters: FastSAC's categorical SAC with norm-bounded networks, a support for
    normalised returns, fewer updates and clipped gradients."""

    actor_hidden: tuple[int, ...] = (256, 256, 256)
    critic_hidden: tuple[int, ...] = (512, 512, 512)
    utd: float = 2.0 / 1024.0
    updates_per_call: int = 4
    publish_every: int = 4
    init_alpha: float = 0.01
    v_min: float = -5.0
    v_max: float = 5.0
    max_grad_norm: float = 1.0
    normalize_rewards: bool = True
    head_scale: float = 0.1  # initial output gain ``s`` of the heads


Config = FlashSACConfig
make_learner = learner_maker(__name__)


# ---------------------------------------------------------------------------------------------
# Norm-bounded networks: [{"w": [in + 1, h], "g": [h], "o": [h]}, ..., {"w": [h, out], "s": [out], "b": [out]}]
# (ensembles: leading [E] on every leaf, vectors [E, 1, n]).
# ---------------------------------------------------------------------------------------------
def _unit_columns(w: Any) -> Any:
    xp = shim.namespace(w)
    return w / xp.sqrt(xp.sum(xp.square(w), axis=-2, keepdims=True) + _EPS * _EPS)


def project_params(params: list[dict]) -> list[dict]:
    """Projects every weight matrix ``w [..., in, out]`` onto unit-norm columns (one per output unit);
    gains and biases are untouched."""
    return [{k: (_unit_columns(v) if k == "w" else v) for k, v in layer.items()} for layer in params]


def flash_init(key: Any, sizes: list[int], xp: shim.Backend, head_scale: float = 0.1,
               ensemble: int = 0) -> list[dict]:
    """Norm-bounded MLP for sizes ``[in, h1, ..., out]`` (unit-norm random columns, g=1, o=0, s=head_scale,
    b=0); ``ensemble=n`` stacks n members (vectors shaped ``[n, 1, size]``)."""
    lead = (ensemble,) if ensemble else ()
    vec = (lambda n: (ensemble, 1, n)) if ensemble else (lambda n: (n,))
    keys = xp.random.split(key, len(sizes) - 1)
    params = []
    for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        n_in = n_in + 1 if i == 0 else n_in  # the constant input feature
        w = _unit_columns(xp.random.normal(keys[i], (*lead, n_in, n_out)))
        if i < len(sizes) - 2:
            params.append({"w": w, "g": xp.ones(vec(n_out), dtype=xp.float32),
                           "o": xp.zeros(vec(n_out), dtype=xp.float32)})
        else:
            params.append({"w": w, "s": xp.full(vec(n_out), head_scale, dtype=xp.float32),
                           "b": xp.zeros(vec(n_out), dtype=xp.float32)})
    return params


def _rms_norm(xp: shim.Backend, x: Any) -> Any:
    return x / xp.sqrt(xp.mean(xp.square(x), axis=-1, keepdims=True) + _EPS)


def flash_apply(params: list[dict], x: Any) -> Any:
    """x [B, in] -> [B, out] (or [E, B, out] for ensemble params)."""
    xp = shim.namespace(params[0]["w"], x)
    # Constant input feature: a norm-bounded bias for the first layer. Without it rmsnorm(x @ W)
    # would be blind to the input's magnitude (it is homogeneous in x).
    h = xp.concat([x, xp.ones_like(x[..., :1])], axis=-1)
    for i, layer in enumerate(params[:-1]):
        z = xp.matmul(h, layer["w"])
        z = xp.relu(_rms_norm(xp, z) * layer["g"] + layer["o"])
        h = h + z if (i > 0 and h.shape == z.shape) else z
    head = params[-1]
    return xp.matmul(_rms_norm(xp, h), head["w"]) * head["s"] + head["b"]


def init_params(key: Any, obs_dim: int, critic_obs_dim: int, action_dim: int, config: FlashSACConfig,
                xp: shim.Backend) -> dict[str, Any]:
    """``{"actor": flash [obs -> 2A], "critic": 2-ensemble flash [critic_obs + A -> num_atoms]}``."""
    ka, kc = xp.random.split(key, 2)
    return {
        "actor": flash_init(ka, [obs_dim, *config.actor_hidden, 2 * action_dim], xp, config.head_scale),
        "critic": flash_init(kc, [critic_obs_dim + action_dim, *config.critic_hidden, config.num_atoms], xp,
                             config.head_scale, ensemble=2),
    }


def act(weights: dict, obs: Any, noise: Any, deterministic: bool = False) -> tuple[Any, dict]:
    """obs [M, obs_dim], noise [M, A] (held for NOISE_HOLD_STEPS steps by the runtime) -> (action, {})."""
    return tanh_gaussian_act(weights, obs, noise, deterministic, flash_apply)


# ---------------------------------------------------------------------------------------------
# Reward normalisation and losses
# ---------------------------------------------------------------------------------------------
def reward_scale(stats: normalizer.RunningStats, config: FlashSACConfig) -> Any:
    """``rms(r) / (1 - gamma)`` from reward statistics ``stats`` (D = 1); rewards are divided by it.

    Returns a scalar (1.0 when ``normalize_rewards`` is off)."""
    xp = shim.namespace(stats.mean)
    if not config.normalize_rewards:
        return xp.asarray(1.0, dtype=xp.float32)
    rms = xp.sqrt(xp.square(stats.mean[0]) + stats.var[0])
    return xp.maximum(rms, 1e-6) / max(1.0 - config.gamma, 1e-3)


def critic_loss(critic: Any, target_critic: Any, actor: Any, log_alpha: Any, norms: Norms, mb: dict,
                eps_next: Any, config: FlashSACConfig) -> tuple[Any, dict]:
    """Categorical twin-critic cross-entropy on normalised rewards (norm-bounded networks)."""
    return categorical_critic_loss(critic, target_critic, actor, log_alpha, norms, mb, eps_next, config,
                                   flash_apply, flash_apply)


def actor_loss(actor: Any, critic: Any, log_alpha: Any, norms: Norms, mb: dict, eps: Any,
               config: FlashSACConfig) -> tuple[Any, tuple]:
    return soft_actor_loss(actor, critic, log_alpha, norms, mb, eps, categorical_q_fn(config, flash_apply),
                           flash_apply, use_min=config.use_cdq)
