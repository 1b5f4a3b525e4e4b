"""JAX learners for the off-policy algorithms (SAC, FastSAC, FlashSAC, RLPD, TD3).

``init(key) -> state``; ``update(state, batch) -> (state, metrics)``; ``weights(state)`` (static).
``batch`` is a dict of arrays shaped ``[U, B, ...]`` (U = ``config.updates_per_call``, B =
``config.batch_size``) with fields ``unilab_jax.fields.REPLAY_FIELDS``; other fields are ignored. ``update``
is ONE ``jax.jit`` that scans U gradient steps; an empty batch ``{}`` returns the state unchanged and no
metrics (the trainer's replay source sends one while the ring warms up). The input state is donated on
accelerators (``DONATE_STATE``).
Normalizer statistics move once per call, from the first of the U minibatches, before the gradient
steps.

The SAC family shares one learner parameterised by the algorithm module, which provides
``init_params``, ``critic_loss``, ``actor_loss``, ``temperature_loss`` and optionally
``project_params`` (applied to the actor, critic and target critic after every step) and
``reward_scale`` (rewards are divided by it; its statistics live in ``state.reward_norm``); with images
(``spec.image_shape``) the losses are ``image_obs``'s wrappers and each step shifts its images first. What does
not depend on the platform (optimizers, initial states, the normalizer step, metrics) is
``learner_common``'s, shared with the MLX learners.

``compiler_options`` (e.g. ``{"xla_backend_optimization_level": 0}``, which halves CPU compile time
for tests and tiny networks) go to ``jax.jit``. ``trace_count`` counts traces of ``update``.

``compute_dtype`` (``learner_common.compute_dtype`` of ``config.compute_dtype`` on this jax backend):
the update is traced inside ``xp.compute_dtype``, so with "bfloat16" every network matmul (forward and
backward) takes bf16 operands with float32 accumulation and results; parameters, optimizer states,
norms, softmax, the C51 projection, log-probs and losses stay float32. "float32" traces exactly the
float32 program.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from unilab_jax import xp as shim
from unilab_jax.algos.offpolicy import image_obs, td3
from unilab_jax.algos.offpolicy import learner_common as common
from unilab_jax.algos.offpolicy.sac import SACState
from unilab_jax.algos.offpolicy.td3 import TD3State
from unilab_jax.core import polyak

XP = shim.get("jax")
# Donated input state on accelerators only (why, and what it gains: unilab_jax/algos/ppo/learner_jax.py).
DONATE_STATE = 0 if jax.default_backend() != "cpu" else ()


def _key_words(key: jax.Array) -> np.ndarray:
    return np.asarray(jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key)


class _Jitted:
    """The JAX side of every off-policy learner: ``_update`` as ONE jit (state donated on accelerators), ``init``."""

    def _compile(self, compiler_options: dict | None) -> None:
        self.compute_dtype = common.compute_dtype(self.config, jax.default_backend())

        def update(state: Any, batch: dict) -> tuple[Any, dict]:
            with XP.compute_dtype(self.compute_dtype):
                return self._update(state, batch)

        self._update_jit = jax.jit(update, donate_argnums=DONATE_STATE, compiler_options=compiler_options)
        self._init_state = jax.jit(self.initial_state, compiler_options=compiler_options)

    def update(self, state: Any, batch: dict) -> tuple[Any, dict]:
        """``batch`` [U, B, ...] -> (new state, metrics averaged over the U steps); ``{}`` (the trainer's
        replay source while the ring warms up) is a no-op."""
        if not batch:
            return state, {}
        return self._update_jit(state, batch)

    def init(self, key: jax.Array) -> Any:
        return self._init_state(self.init_params(_key_words(key)), jax.random.split(key)[1])


def make_td3_learner(algo: ModuleType, config: td3.TD3Config, spec: Any) -> TD3Learner:
    """The registry's factory for TD3."""
    return TD3Learner(config, spec)


class SACFamilyLearner(_Jitted, common.SACFamilyBase):
    """Learner for SAC, FastSAC and FlashSAC (``algo`` is the algorithm module)."""

    def __init__(self, algo: ModuleType, config: Any, spec: Any, compiler_options: dict | None = None):
        super().__init__(algo, config, spec, optax, XP)
        # XLA's CPU backend runs the encoder's convolutions and matmuls inside the scan's loop ~20x slower than
        # the same step unrolled (64x64x6 images, B = 32: 2.7 s vs 0.15 s per step), so on CPU image learners
        # unroll their U steps (still one compile; compile time grows with U).
        self.unroll_steps = bool(self.image_shape) and jax.default_backend() == "cpu"
        self._compile(compiler_options)

    def _update(self, state: SACState, batch: dict) -> tuple[SACState, dict]:
        self.trace_count += 1
        cfg, algo = self.config, self.algo
        project = self._project or (lambda p: p)
        batch = common.prepare_batch(batch, self.batch_fields)
        state, norms = self.normalize(state, batch)

        def step(st: SACState, xs: tuple) -> tuple[SACState, dict]:
            mb, key = xs
            keys = jax.random.split(key, self.step_keys)
            shape = (mb["action"].shape[0], self.noise_dim)
            eps_next = jax.random.normal(keys[0], shape, jnp.float32)
            eps = jax.random.normal(keys[1], shape, jnp.float32)
            if self.critic_noise_shape is not None:
                eps_next = (eps_next, jax.random.uniform(keys[2], self.critic_noise_shape, jnp.float32))
            if self.image_shape:
                mb = self.augment({**mb, image_obs.SHIFT: self.draw_shifts(keys[-1], shape[0])})
            # 1. critics
            (_, c_metrics), c_grads = jax.value_and_grad(self.critic_loss, has_aux=True)(
                st.critic, st.target_critic, st.actor, st.log_alpha, norms, mb, eps_next, cfg)
            updates, critic_opt = self.critic_tx.update(c_grads, st.critic_opt, st.critic)
            critic = project(optax.apply_updates(st.critic, updates))
            # 2.-3. actor against the updated critics, then the temperature (every actor_every-th step)
            if self.actor_every == 1:
                (actor, actor_opt, log_alpha, alpha_opt), a_metrics = actor_step(st, critic, mb, eps)
            else:
                do_actor = (st.steps + 1) % self.actor_every == 0
                (actor, actor_opt, log_alpha, alpha_opt), a_metrics = jax.lax.cond(
                    do_actor, actor_step, skip_actor, st, critic, mb, eps)
                a_metrics["actor_steps"] = do_actor.astype(jnp.float32)
            # 4. targets
            target_critic = project(polyak.polyak(st.target_critic, critic, cfg.tau))
            metrics = {**c_metrics, **a_metrics, "alpha": jnp.exp(log_alpha),
                       "critic_grad_norm": optax.tree.norm(c_grads)}
            new = st._replace(actor=actor, critic=critic, target_critic=target_critic, actor_opt=actor_opt,
                              critic_opt=critic_opt, log_alpha=log_alpha, alpha_opt=alpha_opt, steps=st.steps + 1)
            return new, metrics

        def actor_step(st: SACState, critic: Any, mb: dict, eps: jax.Array) -> tuple[tuple, dict]:
            (_, (a_metrics, log_prob)), a_grads = jax.value_and_grad(self.actor_loss, has_aux=True)(
                st.actor, critic, st.log_alpha, norms, mb, eps, cfg)
            updates, actor_opt = self.actor_tx.update(a_grads, st.actor_opt, st.actor)
            actor = project(optax.apply_updates(st.actor, updates))
            log_alpha, alpha_opt, alpha_loss = st.log_alpha, st.alpha_opt, jnp.zeros((), jnp.float32)
            if cfg.autotune_alpha:
                alpha_loss, g = jax.value_and_grad(algo.temperature_loss)(st.log_alpha, log_prob,
                                                                            self.target_entropy)
                updates, alpha_opt = self.alpha_tx.update(g, st.alpha_opt, st.log_alpha)
                log_alpha = optax.apply_updates(st.log_alpha, updates)
            return (actor, actor_opt, log_alpha, alpha_opt), {**a_metrics, "alpha_loss": alpha_loss,
                                                              "actor_grad_norm": optax.tree.norm(a_grads)}

        def skip_actor(st: SACState, critic: Any, mb: dict, eps: jax.Array) -> tuple[tuple, dict]:
            shapes = jax.eval_shape(actor_step, st, critic, mb, eps)[1]
            return ((st.actor, st.actor_opt, st.log_alpha, st.alpha_opt),
                    jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shapes))

        n = batch["reward"].shape[0]
        keys = jax.random.split(state.key, n + 1)
        state, metrics = jax.lax.scan(step, state, (batch, keys[1:]), unroll=n if self.unroll_steps else 1)
        metrics = self.call_metrics(metrics)
        metrics["reward_scale"] = norms.reward_scale
        return state._replace(key=keys[0]), metrics


class TD3Learner(_Jitted, common.TD3Base):
    """Learner for TD3: delayed actor and target updates every ``policy_delay`` gradient steps."""

    def __init__(self, config: td3.TD3Config, spec: Any, compiler_options: dict | None = None):
        super().__init__(config, spec, optax, XP)
        self._compile(compiler_options)

    def _update(self, state: TD3State, batch: dict) -> tuple[TD3State, dict]:
        self.trace_count += 1
        cfg = self.config
        batch = common.prepare_batch(batch)
        state, norms = self.normalize(state, batch)

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
        return state._replace(key=keys[0]), common.td3_metrics(metrics)
