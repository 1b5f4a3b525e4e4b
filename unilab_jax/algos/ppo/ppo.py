"""PPO: lock-step, on trajectory slots.

The worker side (``act``) and the loss are written against the shim; the learners beside this file
(``learner_jax``, ``learner_mlx``) run them, found through the registry (``unilab_jax.algos``). Published weights are
``{"actor": mlp, "log_std": [A], "obs_norm": RunningStats}``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, NamedTuple

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.config import SelfChecking, hidden_size_problems
from unilab_jax.core import distributions, gae, normalizer, vtrace
from unilab_jax.core import ppo_losses as ppo
from unilab_jax.lazy import learner_maker

SYNC = "lockstep"
BUFFER = "trajectory"
VTRACE = False  # the learners' targets: GAE (V-trace for APPO)


@dataclasses.dataclass(frozen=True)
class PPOConfig(SelfChecking):
    """PPO hyperparameters (rsl_rl-style defaults for legged locomotion)."""

    actor_hidden: tuple[int, ...] = (512, 256, 128)
    critic_hidden: tuple[int, ...] = (512, 256, 128)
    activation: str = "elu"
    init_log_std: float = 0.0
    learning_rate: float = 1e-3
    max_grad_norm: float = 1.0
    horizon: int = 24  # control steps per trajectory slot
    num_epochs: int = 5
    num_minibatches: int = 4
    gamma: float = 0.99
    lam: float = 0.95
    clip_eps: float = 0.2
    value_clip: float = 0.2  # 0 disables value clipping
    vf_coef: float = 1.0
    ent_coef: float = 0.01
    desired_kl: float = 0.01  # 0 disables the KL-adaptive learning rate
    normalize_advantages: bool = True
    normalize_obs: bool = True
    obs_clip: float = 10.0
    # Schedules over the first ``schedule_steps`` env steps (counted as updates x samples per update), then held.
    # lr_schedule: "adaptive" (the KL rule with desired_kl > 0, else learning_rate throughout), "fixed"
    # (learning_rate throughout, desired_kl unused) or "linear" (learning_rate -> final_learning_rate).
    lr_schedule: str = "adaptive"
    final_learning_rate: float = 0.0
    # > 0: the action std's upper bound falls linearly from exp(init_log_std) to final_std (log_std is clamped
    # to it after every optimizer step); 0: no bound.
    final_std: float = 0.0
    schedule_steps: int = 0

    def problems(self) -> list[str]:
        """This class's fields' problems (empty when valid); a subclass appends its own fields' to its base's."""
        problems = hidden_size_problems(self.actor_hidden, self.critic_hidden)
        if min(self.horizon, self.num_epochs, self.num_minibatches) < 1:
            problems.append("horizon, num_epochs and num_minibatches must be positive")
        if not (0.0 <= self.gamma <= 1.0 and 0.0 <= self.lam <= 1.0):
            problems.append(f"need 0 <= gamma <= 1 and 0 <= lam <= 1 (gamma={self.gamma}, lam={self.lam})")
        if not (self.learning_rate > 0 and self.max_grad_norm > 0 and self.clip_eps > 0 and self.obs_clip > 0):
            problems.append("learning_rate, max_grad_norm, clip_eps and obs_clip must be positive")
        if min(self.value_clip, self.vf_coef, self.desired_kl) < 0:
            problems.append("value_clip, vf_coef and desired_kl must be >= 0 (0 disables value clipping, the "
                            "KL-adaptive learning rate)")
        if self.activation not in nets.ACTIVATIONS:
            problems.append(f"activation must be one of {nets.ACTIVATIONS}, got {self.activation!r}")
        return problems + self.schedule_problems()

    def schedule_problems(self) -> list[str]:
        problems = []
        if self.lr_schedule not in LR_SCHEDULES:
            problems.append(f"lr_schedule must be one of {LR_SCHEDULES}, got {self.lr_schedule!r}")
        if self.lr_schedule == "linear" and not self.final_learning_rate > 0:
            problems.append("lr_schedule='linear' needs final_learning_rate > 0")
        if not 0.0 <= self.final_std <= math.exp(self.init_log_std):
            problems.append(f"final_std must be 0 (no bound) or in (0, exp(init_log_std) = "
                            f"{math.exp(self.init_log_std):.3g}], got {self.final_std}")
        scheduled = self.lr_schedule == "linear" or self.final_std > 0
        if self.schedule_steps < 0 or (scheduled and self.schedule_steps == 0):
            problems.append(f"schedule_steps must be positive with lr_schedule='linear' or final_std > 0 "
                            f"(got {self.schedule_steps})")
        return problems


LR_SCHEDULES = ("adaptive", "fixed", "linear")


def schedule_fraction(updates: Any, samples_per_update: int, config: PPOConfig) -> Any:
    """How far the schedules have run before an update: min(env steps so far / schedule_steps, 1) (0 without
    a schedule). ``updates``: the state's update count (a 0-d integer array)."""
    xp = shim.namespace(updates)
    steps = xp.astype(updates, xp.float32) * float(samples_per_update)
    return xp.minimum(steps / float(max(config.schedule_steps, 1)), xp.ones_like(steps))


def scheduled_learning_rate(lr: Any, kl: Any, fraction: Any, config: PPOConfig) -> Any:
    """The learning rate of one optimizer step: ``lr`` (the current one) moved by the KL rule, or the
    schedule's value at ``fraction`` (``schedule_fraction``)."""
    xp = shim.namespace(fraction)
    if config.lr_schedule == "linear":
        return config.learning_rate + (config.final_learning_rate - config.learning_rate) * fraction
    if config.lr_schedule == "fixed":
        return xp.full_like(fraction, config.learning_rate)
    if config.desired_kl > 0:
        # rsl_rl rule: adapt from the KL between the collecting policy and the current one.
        return ppo.kl_adaptive_lr(lr, kl, config.desired_kl)
    return lr


def clamp_log_std(params: dict, fraction: Any, config: PPOConfig) -> dict:
    """``params`` with ``log_std`` at most log of the std bound at ``fraction`` (unchanged with final_std 0)."""
    if config.final_std <= 0:
        return params
    xp = shim.namespace(params["log_std"])
    start = math.exp(config.init_log_std)
    bound = xp.log(start + (config.final_std - start) * fraction)
    return {**params, "log_std": xp.minimum(params["log_std"], xp.astype(bound, params["log_std"].dtype))}


class TrainState(NamedTuple):
    """The whole PPO/APPO training state (one pytree; arrays of the learner's platform)."""

    params: dict
    opt_state: Any
    obs_norm: normalizer.RunningStats
    critic_norm: normalizer.RunningStats
    key: Any
    updates: Any  # number of learner updates so far (int32)


def extras(action_dim: int) -> dict[str, tuple[tuple[int, ...], str]]:
    """Per-transition fields the policy writes besides the task's."""
    return {"log_prob": ((), "float32"), "mean": ((action_dim,), "float32"),
            "log_std": ((action_dim,), "float32")}


def init_params(key: Any, obs_dim: int, critic_obs_dim: int, action_dim: int, config: PPOConfig,
                xp: shim.Backend) -> dict[str, Any]:
    ka, kc = xp.random.split(key, 2)
    return {
        "actor": nets.init(ka, [obs_dim, *config.actor_hidden, action_dim], xp, final_scale=0.01),
        "critic": nets.init(kc, [critic_obs_dim, *config.critic_hidden, 1], xp, final_scale=1.0),
        "log_std": xp.full((action_dim,), config.init_log_std, dtype=xp.float32),
    }


def policy_weights(params: dict[str, Any], obs_norm: Any) -> dict[str, Any]:
    """What workers need to act: the published weight pytree."""
    return {"actor": params["actor"], "log_std": params["log_std"], "obs_norm": obs_norm}


def act(weights: dict[str, Any], obs: Any, noise: Any, deterministic: bool = False) -> tuple[Any, dict]:
    """Gaussian policy. obs [M, obs_dim], noise [M, A] -> action [M, A], extras."""
    return gaussian_act(_actor, weights, obs, noise, deterministic)


def gaussian_act(actor: Actor, weights: dict[str, Any], obs: Any, noise: Any,
                 deterministic: bool = False) -> tuple[Any, dict]:
    """Worker-side step of any PPO variant: ``actor``'s Gaussian (its mean when deterministic) and the
    behaviour-policy fields PPO stores with each transition (``extras``)."""
    xp = shim.namespace(obs)
    mean, log_std = actor(weights, weights["obs_norm"], obs)
    action = mean if deterministic else mean + xp.exp(log_std) * noise
    log_prob = distributions.gaussian_log_prob(action, mean, log_std)
    return action, {"log_prob": log_prob, "mean": mean, "log_std": log_std}


def advantages(params: dict, critic_norm: Any, batch: dict, config: PPOConfig) -> tuple[Any, Any, Any]:
    """Values, GAE advantages and returns for a [T, B] batch (truncation bootstraps)."""
    xp = shim.namespace(batch["reward"])
    values = value(params, critic_norm, batch["critic_obs"])
    next_values = value(params, critic_norm, batch["next_critic_obs"])
    adv, ret = gae.gae(batch["reward"], values, next_values, xp.astype(batch["terminated"], xp.float32),
                       xp.astype(batch["truncated"], xp.float32), config.gamma, config.lam)
    return xp.stop_gradient(values), xp.stop_gradient(adv), xp.stop_gradient(ret)


def value(params: dict, critic_norm: Any, critic_obs: Any) -> Any:
    v = nets.apply(params["critic"], normalizer.normalize(critic_norm, critic_obs))
    return v[..., 0]


# An actor maps (params, obs_norm, obs [..., obs_dim]) to the Gaussian's (mean, log_std) [..., A].
# Variants that change what the policy sees (HORA's teacher, HIM-PPO) pass their own to the
# functions below and reuse the rest of PPO unchanged.
Actor = Callable[[dict, Any, Any], tuple[Any, Any]]


def vtrace_targets(params: dict, obs_norm: Any, critic_norm: Any, batch: dict,
                   config: PPOConfig, actor: Actor | None = None) -> tuple[Any, Any, Any, Any, Any]:
    """APPO targets for a [T, B] batch: values, V-trace policy-gradient advantages, vs, and the
    current policy's mean and log_std.

    Importance ratios compare the current policy with the behaviour policy that collected the
    data (possibly several versions older).
    """
    xp = shim.namespace(batch["reward"])
    values = value(params, critic_norm, batch["critic_obs"])
    next_values = value(params, critic_norm, batch["next_critic_obs"])
    mean, log_std = (actor or _actor)(params, obs_norm, batch["obs"])
    target_log_prob = distributions.gaussian_log_prob(batch["action"], mean, log_std)
    terminated = xp.astype(batch["terminated"], xp.float32)
    done = xp.maximum(terminated, xp.astype(batch["truncated"], xp.float32))
    vs, pg_adv = vtrace.vtrace(values, next_values, batch["reward"], config.gamma * (1.0 - terminated),
                               target_log_prob - batch["log_prob"], done, lam=config.lam)
    sg = xp.stop_gradient
    return sg(values), sg(pg_adv), sg(vs), sg(mean), sg(log_std)


FLAT_FIELDS = ("obs", "critic_obs", "action", "log_prob", "mean", "log_std")


def minibatch_source(params: dict, obs_norm: Any, critic_norm: Any, batch: dict, config: PPOConfig,
                     use_vtrace: bool, actor: Actor | None = None,
                     extra_fields: tuple[str, ...] = ()) -> tuple[dict, dict]:
    """Targets for a [T, B] batch, flattened to [N = T*B, ...] for minibatching, plus metrics.

    With V-trace (APPO) the KL reference (``mean``/``log_std``) is the policy at the start of this
    update, not the stale behaviour policy: the KL-adaptive learning rate measures how far this
    update moves the policy, whatever the lag of the data. ``extra_fields`` are batch fields
    flattened into the minibatches besides PPO's own (e.g. ``next_critic_obs`` for an auxiliary loss).
    """
    xp = shim.namespace(batch["reward"])
    t, b = batch["reward"].shape
    n = t * b
    flat = {k: xp.reshape(batch[k], (n, *batch[k].shape[2:])) for k in FLAT_FIELDS + tuple(extra_fields)}
    if use_vtrace:
        values, adv, ret, mean, log_std = vtrace_targets(params, obs_norm, critic_norm, batch, config, actor)
        flat.update(mean=xp.reshape(mean, flat["mean"].shape), log_std=xp.reshape(log_std, flat["log_std"].shape))
    else:
        values, adv, ret = advantages(params, critic_norm, batch, config)
    flat.update(advantages=xp.reshape(adv, (n,)), returns=xp.reshape(ret, (n,)), values=xp.reshape(values, (n,)))
    return flat, {"value_mean": xp.mean(values), "advantage_std": xp.std(adv)}


def next_state(state: TrainState, params: dict, opt_state: Any, batch: dict, key: Any,
               config: PPOConfig) -> TrainState:
    """The state after an update on the [T, B] ``batch``: new parameters, optimizer state and key, one
    more update, and (``normalize_obs``) the normalizers moved by the batch. They move after the update,
    so its ratios used the normalization the workers acted with."""
    xp = shim.namespace(batch["reward"])
    n = batch["reward"].shape[0] * batch["reward"].shape[1]
    obs_norm, critic_norm = state.obs_norm, state.critic_norm
    if config.normalize_obs:
        obs_norm = normalizer.stats_update(obs_norm, xp.reshape(batch["obs"], (n, -1)))
        critic_norm = normalizer.stats_update(critic_norm, xp.reshape(batch["critic_obs"], (n, -1)))
    return TrainState(params=params, opt_state=opt_state, obs_norm=obs_norm, critic_norm=critic_norm, key=key,
                      updates=state.updates + 1)


def _actor(params: dict, obs_norm: Any, obs: Any) -> tuple[Any, Any]:
    xp = shim.namespace(obs)
    mean = nets.apply(params["actor"], normalizer.normalize(obs_norm, obs))
    return mean, xp.broadcast_to(params["log_std"], mean.shape)


def loss(params: dict, obs_norm: Any, critic_norm: Any, mb: dict, config: PPOConfig,
         asymmetric_clip: bool = False, actor: Actor | None = None) -> tuple[Any, dict]:
    """PPO (or, with ``asymmetric_clip``, APPO) loss on a flat minibatch of N transitions.

    ``mb`` fields are [N, ...]: obs, critic_obs, action, log_prob, mean, log_std (behaviour
    policy), advantages, returns, values (at collection). ``actor``: the policy head (default:
    the MLP on the normalised observation).
    """
    xp = shim.namespace(mb["obs"])
    mean, log_std = (actor or _actor)(params, obs_norm, mb["obs"])
    new_log_prob = distributions.gaussian_log_prob(mb["action"], mean, log_std)
    entropy = distributions.gaussian_entropy(log_std)
    new_values = value(params, critic_norm, mb["critic_obs"])
    if asymmetric_clip:
        total, metrics = vtrace.appo_loss(new_log_prob, mb["log_prob"], mb["advantages"], new_values,
                                          mb["returns"], entropy, config.clip_eps, config.vf_coef,
                                          config.ent_coef, config.normalize_advantages)
    else:
        value_clip = config.value_clip if config.value_clip > 0 else None
        total, metrics = ppo.ppo_loss(new_log_prob, mb["log_prob"], mb["advantages"], new_values, mb["values"],
                                      mb["returns"], entropy, config.clip_eps, value_clip, config.vf_coef,
                                      config.ent_coef, config.normalize_advantages)
    kl = xp.mean(distributions.gaussian_kl(mb["mean"], mb["log_std"], xp.stop_gradient(mean),
                                           xp.stop_gradient(log_std)))
    return total, {**metrics, "kl": kl}


Config = PPOConfig
make_learner = learner_maker(__name__)
