"""JAX learners for the off-policy algorithms (SAC, FastSAC, FlashSAC, TD3).

``init(key) -> state``; ``update(state, batch) -> (state, metrics)``; ``weights(state)`` (static).
``batch`` is a dict of arrays shaped ``[U, B, ...]`` (U = ``config.updates_per_call``, B =
``config.batch_size``) with fields ``BATCH_FIELDS``; other fields are ignored. ``update`` is ONE
``jax.jit`` that scans U gradient steps; an empty batch ``{}`` returns the state unchanged and no
metrics (the trainer's replay source sends one while the ring warms up). The input state is donated on
accelerators (``DONATE_STATE``).
Normalizer statistics move once per call, from the first of the U minibatches, before the gradient
steps.

The SAC family shares one learner parameterised by the algorithm module, which provides
``init_params``, ``critic_loss``, ``actor_loss``, ``temperature_loss`` and optionally
``project_params`` (applied to the actor, critic and target critic after every step) and
``reward_scale`` (rewards are divided by it; its statistics live in ``state.reward_norm``).

``compiler_options`` (e.g. ``{"xla_backend_optimization_level": 0}``, which halves CPU compile time
for tests and tiny networks) go to ``jax.jit``. ``trace_count`` counts traces of ``update``.
"""

from __future__ import annotations

import math
from types import ModuleType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from unilab_jax import nets
from unilab_jax import xp as shim
from unilab_jax.algos import REPLAY_FIELDS as BATCH_FIELDS
from unilab_jax.algos import sac, td3
from unilab_jax.algos.sac import Norms, SACState
from unilab_jax.algos.td3 import TD3State
from unilab_jax.core import normalizer, polyak

XP = shim.get("jax")
# Donated input state on accelerators only (why, and what it gains: unilab_jax/algos/ppo_jax.py).
DONATE_STATE = 0 if jax.default_backend() != "cpu" else ()
NP = shim.get("numpy")


def init_on_numpy(init_params: Any, key: jax.Array, *args: Any, targets: tuple[str, ...] = ()) -> dict:
    """Runs ``init_params(np_key, *args, xp=numpy)`` and moves the result to jax, adding an
    independent copy ``target_<name>`` of each network named in ``targets``.

    Network initialisation is hundreds of small random ops: eagerly in jax each compiles on first
    use (seconds at start-up), in numpy they are instant. The numpy key is derived from ``key``.
    """
    data = np.asarray(jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key)
    np_key = np.asarray(data, dtype=np.uint32).reshape(-1)[:2]
    params = init_params(np_key, *args, xp=NP)
    params.update({f"target_{name}": params[name] for name in targets})
    return {k: nets.convert(v, XP) for k, v in params.items()}  # separate device buffers per entry


def make_optimizer(learning_rate: float, weight_decay: float = 0.0,
                   max_grad_norm: float = 0.0) -> optax.GradientTransformation:
    """Adam (AdamW when ``weight_decay`` > 0), after global-norm clipping when ``max_grad_norm`` > 0."""
    parts = []
    if max_grad_norm > 0:
        parts.append(optax.clip_by_global_norm(max_grad_norm))
    parts.append(optax.adamw(learning_rate, weight_decay=weight_decay) if weight_decay > 0
                 else optax.adam(learning_rate))
    return optax.chain(*parts)


def prepare_batch(batch: dict) -> dict:
    """The fields the update reads, rewards/flags as float32 (bool flags accepted)."""
    out = {k: batch[k] for k in BATCH_FIELDS}
    for k in ("reward", "terminated", "truncated"):
        out[k] = out[k].astype(jnp.float32)
    return out


def update_obs_stats(obs_norm: normalizer.RunningStats, critic_norm: normalizer.RunningStats, batch: dict,
                     enabled: bool) -> tuple[normalizer.RunningStats, normalizer.RunningStats]:
    if not enabled:
        return obs_norm, critic_norm
    return (normalizer.stats_update(obs_norm, batch["obs"][0]),
            normalizer.stats_update(critic_norm, batch["critic_obs"][0]))


def _mean_metrics(metrics: dict) -> dict:
    return jax.tree_util.tree_map(jnp.mean, metrics)


def _skip_or_update(update: Any, state: Any, batch: dict) -> tuple[Any, dict]:
    """An empty batch (``{}``: the trainer's replay source while the ring warms up) is a no-op."""
    if not batch:
        return state, {}
    return update(state, batch)


class SACFamilyLearner:
    """Learner for SAC, FastSAC and FlashSAC (``algo`` is the algorithm module)."""

    def __init__(self, algo: ModuleType, config: Any, spec: Any, compiler_options: dict | None = None):
        self.algo, self.config, self.spec = algo, config, spec
        self.actor_tx = make_optimizer(config.actor_learning_rate, config.weight_decay, config.max_grad_norm)
        self.critic_tx = make_optimizer(config.critic_learning_rate, config.weight_decay, config.max_grad_norm)
        self.alpha_tx = optax.adam(config.alpha_learning_rate)
        self.target_entropy = float(config.target_entropy_per_dim * spec.action_dim)
        self._project = getattr(algo, "project_params", None)
        self._reward_scale = getattr(algo, "reward_scale", None)
        self.trace_count = 0  # times ``update`` was traced (tests assert no retracing)
        self._update_jit = jax.jit(self._update, donate_argnums=DONATE_STATE, compiler_options=compiler_options)
        self._init_state = jax.jit(self._init_state_fn, compiler_options=compiler_options)

    def update(self, state: SACState, batch: dict) -> tuple[SACState, dict]:
        """``batch`` [U, B, ...] -> (new state, metrics averaged over the U steps); ``{}`` is a no-op."""
        return _skip_or_update(self._update_jit, state, batch)

    def init(self, key: jax.Array) -> SACState:
        s = self.spec
        params = init_on_numpy(self.algo.init_params, key, s.obs_dim, s.critic_obs_dim, s.action_dim, self.config,
                               targets=("critic",))
        return self._init_state(params, key)

    def _init_state_fn(self, params: dict, key: jax.Array) -> SACState:
        s = self.spec
        k_state = jax.random.split(key)[1]
        log_alpha = jnp.full((), math.log(self.config.init_alpha), jnp.float32)
        return SACState(
            actor=params["actor"], critic=params["critic"],
            target_critic=params["target_critic"],
            actor_opt=self.actor_tx.init(params["actor"]), critic_opt=self.critic_tx.init(params["critic"]),
            log_alpha=log_alpha, alpha_opt=self.alpha_tx.init(log_alpha),
            obs_norm=normalizer.stats_init(s.obs_dim, XP), critic_norm=normalizer.stats_init(s.critic_obs_dim, XP),
            reward_norm=normalizer.stats_init(1, XP), key=k_state, steps=jnp.zeros((), jnp.int32))

    @staticmethod
    def weights(state: SACState) -> dict:
        return sac.policy_weights(state.actor, state.obs_norm)

    def reward_scale(self, state: SACState) -> jax.Array:
        if self._reward_scale is None:
            return jnp.ones((), jnp.float32)
        return self._reward_scale(state.reward_norm, self.config)

    def _update(self, state: SACState, batch: dict) -> tuple[SACState, dict]:
        self.trace_count += 1
        cfg, algo = self.config, self.algo
        project = self._project or (lambda p: p)
        batch = prepare_batch(batch)
        obs_norm, critic_norm = update_obs_stats(state.obs_norm, state.critic_norm, batch, cfg.normalize_obs)
        reward_norm = state.reward_norm
        if self._reward_scale is not None:
            reward_norm = normalizer.stats_update(reward_norm, batch["reward"][0][:, None])
        state = state._replace(obs_norm=obs_norm, critic_norm=critic_norm, reward_norm=reward_norm)
        norms = Norms(obs_norm, critic_norm, self.reward_scale(state))

        def step(st: SACState, xs: tuple) -> tuple[SACState, dict]:
            mb, key = xs
            k_next, k_pi = jax.random.split(key)
            eps_next = jax.random.normal(k_next, mb["action"].shape, jnp.float32)
            eps = jax.random.normal(k_pi, mb["action"].shape, jnp.float32)
            # 1. critics
            (_, c_metrics), c_grads = jax.value_and_grad(algo.critic_loss, has_aux=True)(
                st.critic, st.target_critic, st.actor, st.log_alpha, norms, mb, eps_next, cfg)
            updates, critic_opt = self.critic_tx.update(c_grads, st.critic_opt, st.critic)
            critic = project(optax.apply_updates(st.critic, updates))
            # 2. actor, against the updated critics
            (_, (a_metrics, log_prob)), a_grads = jax.value_and_grad(algo.actor_loss, has_aux=True)(
                st.actor, critic, st.log_alpha, norms, mb, eps, cfg)
            updates, actor_opt = self.actor_tx.update(a_grads, st.actor_opt, st.actor)
            actor = project(optax.apply_updates(st.actor, updates))
            # 3. temperature
            log_alpha, alpha_opt, alpha_loss = st.log_alpha, st.alpha_opt, jnp.zeros((), jnp.float32)
            if cfg.autotune_alpha:
                alpha_loss, g = jax.value_and_grad(algo.temperature_loss)(st.log_alpha, log_prob,
                                                                            self.target_entropy)
                updates, alpha_opt = self.alpha_tx.update(g, st.alpha_opt, st.log_alpha)
                log_alpha = optax.apply_updates(st.log_alpha, updates)
            # 4. targets
            target_critic = project(polyak.polyak(st.target_critic, critic, cfg.tau))
            metrics = {**c_metrics, **a_metrics, "alpha": jnp.exp(log_alpha), "alpha_loss": alpha_loss,
                       "critic_grad_norm": optax.tree.norm(c_grads), "actor_grad_norm": optax.tree.norm(a_grads)}
            new = st._replace(actor=actor, critic=critic, target_critic=target_critic, actor_opt=actor_opt,
                              critic_opt=critic_opt, log_alpha=log_alpha, alpha_opt=alpha_opt, steps=st.steps + 1)
            return new, metrics

        n = batch["reward"].shape[0]
        keys = jax.random.split(state.key, n + 1)
        state, metrics = jax.lax.scan(step, state, (batch, keys[1:]))
        metrics = _mean_metrics(metrics)
        metrics["reward_scale"] = norms.reward_scale
        return state._replace(key=keys[0]), metrics


class TD3Learner:
    """Learner for TD3: delayed actor and target updates every ``policy_delay`` gradient steps."""

    def __init__(self, config: td3.TD3Config, spec: Any, compiler_options: dict | None = None):
        self.config, self.spec = config, spec
        self.actor_tx = make_optimizer(config.actor_learning_rate, config.weight_decay, config.max_grad_norm)
        self.critic_tx = make_optimizer(config.critic_learning_rate, config.weight_decay, config.max_grad_norm)
        self.trace_count = 0
        self._update_jit = jax.jit(self._update, donate_argnums=DONATE_STATE, compiler_options=compiler_options)
        self._init_state = jax.jit(self._init_state_fn, compiler_options=compiler_options)

    def update(self, state: TD3State, batch: dict) -> tuple[TD3State, dict]:
        """``batch`` [U, B, ...] -> (new state, metrics averaged over the U steps); ``{}`` is a no-op."""
        return _skip_or_update(self._update_jit, state, batch)

    def init(self, key: jax.Array) -> TD3State:
        s = self.spec
        params = init_on_numpy(td3.init_params, key, s.obs_dim, s.critic_obs_dim, s.action_dim, self.config,
                               targets=("actor", "critic"))
        return self._init_state(params, key)

    def _init_state_fn(self, params: dict, key: jax.Array) -> TD3State:
        s = self.spec
        k_state = jax.random.split(key)[1]
        return TD3State(
            actor=params["actor"], critic=params["critic"], target_actor=params["target_actor"],
            target_critic=params["target_critic"], actor_opt=self.actor_tx.init(params["actor"]),
            critic_opt=self.critic_tx.init(params["critic"]),
            obs_norm=normalizer.stats_init(s.obs_dim, XP), critic_norm=normalizer.stats_init(s.critic_obs_dim, XP),
            explore_std=jnp.asarray(self.config.explore_std, jnp.float32), key=k_state,
            steps=jnp.zeros((), jnp.int32))

    @staticmethod
    def weights(state: TD3State) -> dict:
        return {"actor": state.actor, "obs_norm": state.obs_norm, "explore_std": state.explore_std}

    def _update(self, state: TD3State, batch: dict) -> tuple[TD3State, dict]:
        self.trace_count += 1
        cfg = self.config
        batch = prepare_batch(batch)
        obs_norm, critic_norm = update_obs_stats(state.obs_norm, state.critic_norm, batch, cfg.normalize_obs)
        state = state._replace(obs_norm=obs_norm, critic_norm=critic_norm)
        norms = Norms(obs_norm, critic_norm, jnp.ones((), jnp.float32))

        def actor_step(st: TD3State, mb: dict) -> tuple[TD3State, jax.Array]:
            (loss, _), grads = jax.value_and_grad(td3.actor_loss, has_aux=True)(st.actor, st.critic, norms, mb)
            updates, actor_opt = self.actor_tx.update(grads, st.actor_opt, st.actor)
            actor = optax.apply_updates(st.actor, updates)
            return st._replace(actor=actor, actor_opt=actor_opt,
                               target_actor=polyak.polyak(st.target_actor, actor, cfg.tau),
                               target_critic=polyak.polyak(st.target_critic, st.critic, cfg.tau)), loss

        def step(st: TD3State, xs: tuple) -> tuple[TD3State, dict]:
            mb, key = xs
            eps_next = jax.random.normal(key, mb["action"].shape, jnp.float32)
            (_, c_metrics), c_grads = jax.value_and_grad(td3.critic_loss, has_aux=True)(
                st.critic, st.target_actor, st.target_critic, norms, mb, eps_next, cfg)
            updates, critic_opt = self.critic_tx.update(c_grads, st.critic_opt, st.critic)
            st = st._replace(critic=optax.apply_updates(st.critic, updates), critic_opt=critic_opt)
            # Fujimoto's schedule: the actor moves after every policy_delay-th critic step.
            do_actor = ((st.steps + 1) % cfg.policy_delay) == 0
            st, a_loss = jax.lax.cond(do_actor, actor_step, lambda s, _: (s, jnp.zeros((), jnp.float32)), st, mb)
            metrics = {**c_metrics, "actor_loss_sum": a_loss, "actor_steps": do_actor.astype(jnp.float32),
                       "critic_grad_norm": optax.tree.norm(c_grads)}
            return st._replace(steps=st.steps + 1), metrics

        n = batch["reward"].shape[0]
        keys = jax.random.split(state.key, n + 1)
        state, metrics = jax.lax.scan(step, state, (batch, keys[1:]))
        actor_steps = jnp.sum(metrics.pop("actor_steps"))
        actor_loss_sum = jnp.sum(metrics.pop("actor_loss_sum"))
        metrics = _mean_metrics(metrics)
        # Mean over the steps that updated the actor (0 when none did in this call).
        metrics["actor_loss"] = actor_loss_sum / jnp.maximum(actor_steps, 1.0)
        metrics["actor_steps"] = actor_steps
        return state._replace(key=keys[0]), metrics
