"""MLX learners for the off-policy algorithms (SAC, FastSAC, FlashSAC, TD3), the same math as
``unilab_jax.algos.offpolicy_jax``.

``SACFamilyLearner(algo, config, spec)`` and ``TD3Learner(config, spec)`` expose the JAX learners'
interface::

    learner = SACFamilyLearner(sac, config, spec)
    state = learner.init(mx.random.key(0))          # SACState of mx arrays
    state, metrics = learner.update(state, batch)    # batch: dict of arrays [U, B, ...]; {} is a no-op
    weights = SACFamilyLearner.weights(state)

The losses are the algorithm modules' shim-written functions run on mlx arrays (``critic_loss``,
``actor_loss``, ``temperature_loss``, optional ``project_params`` and ``reward_scale``); the
optimizers are ``unilab_mlx.optim``'s optax twins built exactly as ``offpolicy_jax.make_optimizer``
(``chain([clip_by_global_norm,] adam | adamw)``), so optimizer states have the same layout (dicts and
tuples instead of optax NamedTuples) and :func:`state_from_numpy` moves a JAX state here by name.

Network initialisation runs on numpy from the key's two uint32 words, as the JAX learner does, so
``init`` with the same key value gives the JAX learner's parameters bit for bit.

Compile boundaries. The JAX learner scans the U gradient steps inside one jit. MLX has no scan, so
here ONE gradient step is a compiled pure function of explicit state
``(nets, opt states, log_alpha, ...), norms, minibatch, noise -> (new nets/opt states, metrics)``,
traced once and reused; a Python loop drives it with exactly one ``mx.eval`` per step. As in JAX,
the normalizer statistics (and FlashSAC's reward statistics) move once per call from the first of
the U minibatches before the gradient steps. TD3's delayed actor/target step is decided in Python
from the step counter (read once per call): two compiled variants, critic-only and critic+actor,
replace ``lax.cond``.

Randomness: the state's key is split into ``U + 1`` keys exactly as in JAX (the first becomes the
next state's key); SAC-family step ``i`` splits ``keys[i + 1]`` into ``(k_next, k_pi)`` and draws
``eps_next``/``eps`` ~ N(0, 1) of the action's shape; TD3 draws ``eps_next`` from ``keys[i + 1]``.
MLX's normal draws differ from JAX's for the same key, so parity tests inject the JAX draws through
``update(..., noise={"eps_next": [U, B, A], "eps": [U, B, A]})`` (TD3: ``eps_next`` only).

This module imports mlx and numpy (and the shim-written ``unilab_jax`` modules) only, never jax or
optax.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from types import ModuleType
from typing import Any

import mlx.core as mx
import numpy as np

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.algos import REPLAY_FIELDS as BATCH_FIELDS
from unilab_jax.algos import sac, td3
from unilab_jax.algos.sac import Norms, SACState
from unilab_jax.algos.td3 import TD3State
from unilab_jax.core import normalizer, polyak
from unilab_mlx import optim
from unilab_mlx.ppo import _fill, state_to_numpy

__all__ = ["SACState", "TD3State", "SACFamilyLearner", "TD3Learner", "make_optimizer", "state_from_numpy",
           "state_to_numpy", "BATCH_FIELDS"]

XP = shim.get("mlx")
NP = shim.get("numpy")


def make_optimizer(learning_rate: float, weight_decay: float = 0.0,
                   max_grad_norm: float = 0.0) -> optim.GradientTransformation:
    """Adam (AdamW when ``weight_decay`` > 0), after global-norm clipping when ``max_grad_norm`` > 0."""
    parts = []
    if max_grad_norm > 0:
        parts.append(optim.clip_by_global_norm(max_grad_norm))
    parts.append(optim.adamw(learning_rate, weight_decay=weight_decay) if weight_decay > 0
                 else optim.adam(learning_rate))
    return optim.chain(*parts)


def _init_on_numpy(init_params: Any, key: Any, *args: Any, targets: tuple[str, ...] = ()) -> dict:
    """``init_params(np_key, *args, xp=numpy)`` moved to mlx (``offpolicy_jax.init_on_numpy``'s twin:
    the numpy key is the key's two uint32 words), plus a copy ``target_<name>`` per name in ``targets``."""
    np_key = np.asarray(key, dtype=np.uint32).reshape(-1)[:2]
    params = init_params(np_key, *args, xp=NP)
    params.update({f"target_{name}": params[name] for name in targets})
    return {k: nets.convert(v, XP) for k, v in params.items()}


def _as_key(key: Any) -> mx.array:
    if isinstance(key, int):
        return mx.random.key(key)
    return key if isinstance(key, mx.array) else mx.array(np.asarray(key, dtype=np.uint32))


def prepare_batch(batch: Mapping[str, Any]) -> dict:
    """The fields the update reads as mx arrays, rewards/flags as float32 (bool flags accepted)."""
    out = {k: batch[k] if isinstance(batch[k], mx.array) else mx.array(np.asarray(batch[k])) for k in BATCH_FIELDS}
    for k in ("reward", "terminated", "truncated"):
        out[k] = out[k].astype(mx.float32)
    return out


def update_obs_stats(obs_norm: normalizer.RunningStats, critic_norm: normalizer.RunningStats, batch: dict,
                     enabled: bool) -> tuple[normalizer.RunningStats, normalizer.RunningStats]:
    if not enabled:
        return obs_norm, critic_norm
    return (normalizer.stats_update(obs_norm, batch["obs"][0]),
            normalizer.stats_update(critic_norm, batch["critic_obs"][0]))


def _noise(noise: Mapping[str, Any] | None, name: str, i: int, shape: tuple, key: mx.array) -> mx.array:
    """Step ``i``'s standard-normal draw: the injected ``noise[name][i]`` or ``N(0, 1)`` from ``key``."""
    if noise is not None:
        a = noise[name][i]
        a = a if isinstance(a, mx.array) else mx.array(np.asarray(a, dtype=np.float32))
        if tuple(a.shape) != tuple(shape):
            raise ValueError(f"noise[{name!r}][{i}] has shape {tuple(a.shape)}, {tuple(shape)} expected")
        return a.astype(mx.float32)
    return mx.random.normal(shape=tuple(shape), dtype=mx.float32, key=key)


def _check_noise(noise: Mapping[str, Any] | None, names: tuple[str, ...], n: int) -> None:
    if noise is None:
        return
    for name in names:
        if name not in noise or len(noise[name]) < n:
            raise ValueError(f"noise needs {names} with at least {n} steps each")


def _mean_metrics(step_metrics: list[dict]) -> dict:
    return {k: mx.mean(mx.stack([m[k] for m in step_metrics])) for k in step_metrics[0]}


class SACFamilyLearner:
    """Learner for SAC, FastSAC and FlashSAC (``algo`` is the algorithm module)."""

    def __init__(self, algo: ModuleType, config: Any, spec: Any):
        self.algo, self.config, self.spec = algo, config, spec
        self.actor_tx = make_optimizer(config.actor_learning_rate, config.weight_decay, config.max_grad_norm)
        self.critic_tx = make_optimizer(config.critic_learning_rate, config.weight_decay, config.max_grad_norm)
        self.alpha_tx = optim.adam(config.alpha_learning_rate)
        self.target_entropy = float(config.target_entropy_per_dim * spec.action_dim)
        self._project = getattr(algo, "project_params", None)
        self._reward_scale = getattr(algo, "reward_scale", None)
        self.trace_count = 0  # traces of the compiled gradient step
        self._step = mx.compile(self._step_fn)

    def init(self, key: Any) -> SACState:
        s, key = self.spec, _as_key(key)
        params = _init_on_numpy(self.algo.init_params, key, s.obs_dim, s.critic_obs_dim, s.action_dim, self.config,
                                targets=("critic",))
        k_state = XP.random.split(key, 2)[1]
        log_alpha = mx.array(math.log(self.config.init_alpha), dtype=mx.float32)
        state = SACState(
            actor=params["actor"], critic=params["critic"], target_critic=params["target_critic"],
            actor_opt=self.actor_tx.init(params["actor"]), critic_opt=self.critic_tx.init(params["critic"]),
            log_alpha=log_alpha, alpha_opt=self.alpha_tx.init(log_alpha),
            obs_norm=normalizer.stats_init(s.obs_dim, XP), critic_norm=normalizer.stats_init(s.critic_obs_dim, XP),
            reward_norm=normalizer.stats_init(1, XP), key=k_state, steps=mx.array(0, dtype=mx.int32))
        mx.eval(state)
        return state

    @staticmethod
    def weights(state: SACState) -> dict:
        return sac.policy_weights(state.actor, state.obs_norm)

    def reward_scale(self, state: SACState) -> mx.array:
        if self._reward_scale is None:
            return mx.array(1.0, dtype=mx.float32)
        return self._reward_scale(state.reward_norm, self.config)

    def _step_fn(self, nets_opt: tuple, norms: tuple, mb: dict, eps_next: mx.array,
                 eps: mx.array) -> tuple[tuple, dict]:
        """One gradient step (critics, actor, temperature, Polyak), pure in its arguments."""
        self.trace_count += 1
        cfg, algo = self.config, self.algo
        project = self._project or (lambda p: p)
        actor, critic, target_critic, actor_opt, critic_opt, log_alpha, alpha_opt, steps = nets_opt
        norms = Norms(*norms)
        # 1. critics
        (_, c_metrics), c_grads = XP.value_and_grad(algo.critic_loss, has_aux=True)(
            critic, target_critic, actor, log_alpha, norms, mb, eps_next, cfg)
        updates, new_critic_opt = self.critic_tx.update(c_grads, critic_opt, critic)
        new_critic = project(optim.apply_updates(critic, updates))
        # 2. actor, against the updated critics
        (_, (a_metrics, log_prob)), a_grads = XP.value_and_grad(algo.actor_loss, has_aux=True)(
            actor, new_critic, log_alpha, norms, mb, eps, cfg)
        updates, new_actor_opt = self.actor_tx.update(a_grads, actor_opt, actor)
        new_actor = project(optim.apply_updates(actor, updates))
        # 3. temperature
        new_log_alpha, new_alpha_opt, alpha_loss = log_alpha, alpha_opt, mx.array(0.0, dtype=mx.float32)
        if cfg.autotune_alpha:
            alpha_loss, g = XP.value_and_grad(algo.temperature_loss)(log_alpha, log_prob, self.target_entropy)
            updates, new_alpha_opt = self.alpha_tx.update(g, alpha_opt, log_alpha)
            new_log_alpha = optim.apply_updates(log_alpha, updates)
        # 4. targets
        new_target = project(polyak.polyak(target_critic, new_critic, cfg.tau))
        metrics = {**c_metrics, **a_metrics, "alpha": mx.exp(new_log_alpha), "alpha_loss": alpha_loss,
                   "critic_grad_norm": optim.global_norm(c_grads), "actor_grad_norm": optim.global_norm(a_grads)}
        return (new_actor, new_critic, new_target, new_actor_opt, new_critic_opt, new_log_alpha, new_alpha_opt,
                steps + 1), metrics

    def update(self, state: SACState, batch: Mapping[str, Any],
               noise: Mapping[str, Any] | None = None) -> tuple[SACState, dict]:
        """``batch`` [U, B, ...] -> (new state, metrics averaged over the U steps); ``{}`` is a no-op.

        ``noise`` (testing/parity only): ``{"eps_next": [U, B, A], "eps": [U, B, A]}`` replacing the
        standard-normal draws made from the state's key (the key still advances as usual).
        """
        if not batch:
            return state, {}
        cfg = self.config
        batch = prepare_batch(batch)
        obs_norm, critic_norm = update_obs_stats(state.obs_norm, state.critic_norm, batch, cfg.normalize_obs)
        reward_norm = state.reward_norm
        if self._reward_scale is not None:
            reward_norm = normalizer.stats_update(reward_norm, batch["reward"][0][:, None])
        state = state._replace(obs_norm=obs_norm, critic_norm=critic_norm, reward_norm=reward_norm)
        scale = self.reward_scale(state).astype(mx.float32)
        norms = (obs_norm, critic_norm, scale)

        n = batch["reward"].shape[0]
        _check_noise(noise, ("eps_next", "eps"), n)
        keys = XP.random.split(state.key, n + 1)
        carry = (state.actor, state.critic, state.target_critic, state.actor_opt, state.critic_opt,
                 state.log_alpha, state.alpha_opt, state.steps)
        step_metrics = []
        for i in range(n):
            mb = {k: v[i] for k, v in batch.items()}
            shape = tuple(mb["action"].shape)
            k_next, k_pi = XP.random.split(keys[i + 1], 2)
            eps_next = _noise(noise, "eps_next", i, shape, k_next)
            eps = _noise(noise, "eps", i, shape, k_pi)
            carry, m = self._step(carry, norms, mb, eps_next, eps)
            mx.eval(carry, m)  # one eval per compiled step
            step_metrics.append(m)
        metrics = _mean_metrics(step_metrics)
        metrics["reward_scale"] = scale
        actor, critic, target_critic, actor_opt, critic_opt, log_alpha, alpha_opt, steps = carry
        new = state._replace(actor=actor, critic=critic, target_critic=target_critic, actor_opt=actor_opt,
                             critic_opt=critic_opt, log_alpha=log_alpha, alpha_opt=alpha_opt, steps=steps,
                             key=keys[0])
        mx.eval(new, metrics)
        return new, metrics


class TD3Learner:
    """Learner for TD3: delayed actor and target updates every ``policy_delay`` gradient steps."""

    def __init__(self, config: td3.TD3Config, spec: Any):
        self.config, self.spec = config, spec
        self.actor_tx = make_optimizer(config.actor_learning_rate, config.weight_decay, config.max_grad_norm)
        self.critic_tx = make_optimizer(config.critic_learning_rate, config.weight_decay, config.max_grad_norm)
        self.trace_count = 0
        self._steps = {flag: mx.compile(functools.partial(self._step_fn, do_actor=flag)) for flag in (False, True)}

    def init(self, key: Any) -> TD3State:
        s, key = self.spec, _as_key(key)
        params = _init_on_numpy(td3.init_params, key, s.obs_dim, s.critic_obs_dim, s.action_dim, self.config,
                                targets=("actor", "critic"))
        k_state = XP.random.split(key, 2)[1]
        state = TD3State(
            actor=params["actor"], critic=params["critic"], target_actor=params["target_actor"],
            target_critic=params["target_critic"], actor_opt=self.actor_tx.init(params["actor"]),
            critic_opt=self.critic_tx.init(params["critic"]),
            obs_norm=normalizer.stats_init(s.obs_dim, XP), critic_norm=normalizer.stats_init(s.critic_obs_dim, XP),
            explore_std=mx.array(self.config.explore_std, dtype=mx.float32), key=k_state,
            steps=mx.array(0, dtype=mx.int32))
        mx.eval(state)
        return state

    @staticmethod
    def weights(state: TD3State) -> dict:
        return {"actor": state.actor, "obs_norm": state.obs_norm, "explore_std": state.explore_std}

    def _step_fn(self, nets_opt: tuple, norms: tuple, mb: dict, eps_next: mx.array,
                 do_actor: bool) -> tuple[tuple, dict]:
        """One critic step, then (``do_actor``) the actor step and both Polyak updates."""
        self.trace_count += 1
        cfg = self.config
        actor, critic, target_actor, target_critic, actor_opt, critic_opt, steps = nets_opt
        norms = Norms(*norms)
        (_, c_metrics), c_grads = XP.value_and_grad(td3.critic_loss, has_aux=True)(
            critic, target_actor, target_critic, norms, mb, eps_next, cfg)
        updates, critic_opt = self.critic_tx.update(c_grads, critic_opt, critic)
        critic = optim.apply_updates(critic, updates)
        a_loss = mx.array(0.0, dtype=mx.float32)
        if do_actor:
            (a_loss, _), grads = XP.value_and_grad(td3.actor_loss, has_aux=True)(actor, critic, norms, mb)
            updates, actor_opt = self.actor_tx.update(grads, actor_opt, actor)
            actor = optim.apply_updates(actor, updates)
            target_actor = polyak.polyak(target_actor, actor, cfg.tau)
            target_critic = polyak.polyak(target_critic, critic, cfg.tau)
        metrics = {**c_metrics, "actor_loss_sum": a_loss,
                   "actor_steps": mx.array(1.0 if do_actor else 0.0, dtype=mx.float32),
                   "critic_grad_norm": optim.global_norm(c_grads)}
        return (actor, critic, target_actor, target_critic, actor_opt, critic_opt, steps + 1), metrics

    def update(self, state: TD3State, batch: Mapping[str, Any],
               noise: Mapping[str, Any] | None = None) -> tuple[TD3State, dict]:
        """``batch`` [U, B, ...] -> (new state, metrics averaged over the U steps); ``{}`` is a no-op.

        ``noise`` (testing/parity only): ``{"eps_next": [U, B, A]}`` replacing the target-smoothing
        draws made from the state's key (the key still advances as usual).
        """
        if not batch:
            return state, {}
        cfg = self.config
        batch = prepare_batch(batch)
        obs_norm, critic_norm = update_obs_stats(state.obs_norm, state.critic_norm, batch, cfg.normalize_obs)
        state = state._replace(obs_norm=obs_norm, critic_norm=critic_norm)
        norms = (obs_norm, critic_norm, mx.array(1.0, dtype=mx.float32))

        n = batch["reward"].shape[0]
        _check_noise(noise, ("eps_next",), n)
        keys = XP.random.split(state.key, n + 1)
        step0 = int(state.steps.item())  # the delay schedule is decided on the host (one read per call)
        carry = (state.actor, state.critic, state.target_actor, state.target_critic, state.actor_opt,
                 state.critic_opt, state.steps)
        step_metrics = []
        for i in range(n):
            mb = {k: v[i] for k, v in batch.items()}
            eps_next = _noise(noise, "eps_next", i, tuple(mb["action"].shape), keys[i + 1])
            # Fujimoto's schedule: the actor moves after every policy_delay-th critic step.
            do_actor = (step0 + i + 1) % cfg.policy_delay == 0
            carry, m = self._steps[do_actor](carry, norms, mb, eps_next)
            mx.eval(carry, m)  # one eval per compiled step
            step_metrics.append(m)
        actor_steps = mx.sum(mx.stack([m.pop("actor_steps") for m in step_metrics]))
        actor_loss_sum = mx.sum(mx.stack([m.pop("actor_loss_sum") for m in step_metrics]))
        metrics = _mean_metrics(step_metrics)
        metrics["actor_loss"] = actor_loss_sum / mx.maximum(actor_steps, 1.0)
        metrics["actor_steps"] = actor_steps
        actor, critic, target_actor, target_critic, actor_opt, critic_opt, steps = carry
        new = state._replace(actor=actor, critic=critic, target_actor=target_actor, target_critic=target_critic,
                             actor_opt=actor_opt, critic_opt=critic_opt, steps=steps, key=keys[0])
        mx.eval(new, metrics)
        return new, metrics


def state_from_numpy(tree: Any, like: Any) -> Any:
    """``tree`` (a SACState/TD3State of numpy or JAX arrays, e.g. the JAX learner's) as an MLX state.

    ``like`` is an MLX state giving structure, shapes and dtypes (``learner.init(key)``). The source
    is read by name (dict keys, NamedTuple fields: optax's ``ScaleByAdamState``/``EmptyState`` map onto
    ``unilab_mlx.optim``'s dicts); leaves go through ``np.asarray`` (no jax import here). A missing
    field or a shape mismatch raises, naming the leaf.
    """
    out = _fill(like, tree)
    mx.eval(out)
    return out
