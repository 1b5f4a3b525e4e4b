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
not depend on the platform (optimizers, initial states, the normalizer step, the order of a gradient step:
``learner_common.sac_step`` / ``td3_step``, given this platform's ``OPS``, metrics) is ``learner_common``'s,
shared with the MLX learners.

``compiler_options`` (e.g. ``{"xla_backend_optimization_level": 0}``, which halves CPU compile time
for tests and tiny networks) go to ``jax.jit``. ``trace_count`` counts traces of ``update``.

``compute_dtype`` (``learner_common.compute_dtype`` of ``config.compute_dtype`` on this jax backend):
the update is traced inside ``xp.compute_dtype``, so with "bfloat16" every network matmul (forward and
backward) takes bf16 operands with float32 accumulation and results; parameters, optimizer states,
norms, softmax, the C51 projection, log-probs and losses stay float32. "float32" traces exactly the
float32 program. ``config.ln_forward`` / ``ln_backward`` ("auto", "xla" or "pallas":
``learner_common.resolve_ln_kernels``, ``mixed_precision.ln_kernels``) pick the forward / backward pass of the bf16
LayerNorm + ReLU layers.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from unilab_jax import mixed_precision
from unilab_jax import xp as shim
from unilab_jax.algos.offpolicy import image_obs, td3
from unilab_jax.algos.offpolicy import learner_common as common
from unilab_jax.algos.offpolicy.sac import SACState
from unilab_jax.algos.offpolicy.td3 import TD3State

XP = shim.get("jax")
# Donated input state on accelerators only (why, and what it gains: unilab_jax/algos/ppo/learner_jax.py).
DONATE_STATE = 0 if jax.default_backend() != "cpu" else ()


def _zeros_like_metrics(actor_step: Any, *operands: Any) -> dict:
    """Zeros shaped like ``actor_step``'s metrics (``lax.cond``'s other branch must match its structure)."""
    shapes = jax.eval_shape(actor_step, *operands)[1]
    return jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shapes)


# How the JAX learners take gradients and apply updates (the steps' order is learner_common's).
OPS = common.Ops(value_and_grad=jax.value_and_grad, apply_updates=optax.apply_updates, global_norm=optax.tree.norm,
                 cond=jax.lax.cond, skip_metrics=_zeros_like_metrics)


def _key_words(key: jax.Array) -> np.ndarray:
    return np.asarray(jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key)


class _Jitted:
    """The JAX side of every off-policy learner: ``_update`` as ONE jit (state donated on accelerators), ``init``."""

    def _compile(self, compiler_options: dict | None) -> None:
        self.compute_dtype = common.compute_dtype(self.config, jax.default_backend())
        # for one device; training.sharding.DataParallel sets its own (XLA's programs) before it compiles
        self.ln_kernels = common.resolve_ln_kernels(self.config, self.compute_dtype, jax.devices()[:1])
        self._update_jit = jax.jit(self.traced_update, donate_argnums=DONATE_STATE, compiler_options=compiler_options)
        self._init_state = jax.jit(self.initial_state, compiler_options=compiler_options)

    def traced_update(self, state: Any, batch: dict) -> tuple[Any, dict]:
        """The pure update as this learner compiles it: ``_update`` traced in the learner's ``compute_dtype``
        and with the forward and backward kernels of its bf16 LayerNorm layers in ``self.ln_kernels`` (what
        ``config.ln_forward`` / ``ln_backward`` resolve to; ``training.sharding`` compiles this same function over
        several devices)."""
        kernels = mixed_precision.ln_kernels(*self.ln_kernels)
        with XP.compute_dtype(self.compute_dtype), kernels:
            return self._update(state, batch)

    def update(self, state: Any, batch: dict) -> tuple[Any, dict]:
        """``batch`` [U, B, ...] -> (new state, metrics averaged over the U steps); ``{}`` (the trainer's
        replay source while the ring warms up) is a no-op."""
        if not batch:
            return state, {}
        return self._update_jit(state, batch)

    def init(self, key: jax.Array) -> Any:
        return self._init_state(self.init_params(_key_words(key)), jax.random.split(key)[1])

    def precompile(self, state: Any, batch_layout: dict[str, tuple]) -> None:
        """Compiles ``update`` for a state shaped, typed and placed like ``state`` (lowered, not read nor donated) and
        minibatches of ``batch_layout`` (``{field: (shape, dtype)}``, arrays left on the default device), so that the
        first call with such arguments runs at once: the trainer does this from the start of a run, while the workers
        start and the rings fill (XLA's compile of a large update takes 14-18 s on the H100 machine)."""
        batch = {k: jax.ShapeDtypeStruct(shape, jax.dtypes.canonicalize_dtype(dtype))
                 for k, (shape, dtype) in batch_layout.items()}
        self._update_jit.lower(state, batch).compile()


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
            # The actor and the temperature move on every actor_every-th step (lax.cond; always when it is 1).
            do_actor = True if self.actor_every == 1 else (st.steps + 1) % self.actor_every == 0
            nets, metrics = common.sac_step(self, OPS, common.sac_nets(st), norms, mb, eps_next, eps, do_actor)
            return st._replace(**nets._asdict()), metrics

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

        def step(st: TD3State, xs: tuple) -> tuple[TD3State, dict]:
            mb, key = xs
            eps_next = jax.random.normal(key, mb["action"].shape, jnp.float32)
            # Fujimoto's schedule: the actor moves after every policy_delay-th critic step (lax.cond).
            do_actor = ((st.steps + 1) % cfg.policy_delay) == 0
            nets, metrics = common.td3_step(self, OPS, common.td3_nets(st), norms, mb, eps_next, do_actor)
            return st._replace(**nets._asdict()), metrics

        n = batch["reward"].shape[0]
        keys = jax.random.split(state.key, n + 1)
        state, metrics = jax.lax.scan(step, state, (batch, keys[1:]))
        return state._replace(key=keys[0]), common.td3_metrics(metrics)
