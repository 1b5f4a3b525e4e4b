"""MLX learner for PPO and APPO, the same math as ``learner_jax``.

``Learner(config, spec, use_vtrace=False)`` exposes the JAX learner's interface::

    learner = Learner(config, spec)
    state = learner.init(mx.random.key(0))            # TrainState of mx arrays
    state, metrics = learner.update(state, batch)      # batch: dict of mx arrays [T, B, ...]
    weights = Learner.weights(state)                   # what the workers act with

The loss, targets (GAE, or V-trace for APPO), KL-adaptive learning rate and normalizer are the
shim-written functions of ``ppo`` / ``unilab_jax.core`` run on mlx arrays; the
optimizer is ``unilab_mlx.optim``'s optax twin ``chain(clip_by_global_norm, inject_hyperparams(adam))``,
so the optimizer state has the same layout (dicts and tuples instead of optax's NamedTuples) and
:func:`state_from_numpy` moves a JAX ``TrainState`` here leaf by leaf.

Compile boundaries. The JAX learner jits the whole update with ``lax.scan`` over epochs and
minibatches inside (DESIGN "Style" 4). MLX has no scan, and unrolling every minibatch step into one
graph would make the compiled graph grow with ``num_epochs * num_minibatches``. On MLX the update is
therefore:

* one compiled function for the targets (values, advantages, returns; evaluated lazily with the
  first step);
* one compiled minibatch step, a pure function
  ``(params, opt_state, obs_norm, critic_norm, flat, idx, fraction) -> (params, opt_state, metrics)`` (the
  minibatch gather by ``idx``, value_and_grad of the loss, KL-adaptive or scheduled learning rate written
  into the injected hyperparameter before the optimizer update, Adam, the std bound), traced once and reused;
* a Python loop over epochs and minibatches driving that step, with exactly one ``mx.eval`` per
  step (the state is the explicit input and output, nothing is captured or mutated);
* the normalizer statistics moved after the PPO steps, and one final ``mx.eval`` of the new state
  and metrics.

Randomness is explicit: the state's key is split into ``num_epochs + 1`` keys, the first becomes
the next state's key and the others draw each epoch's minibatch permutation
(``mx.random.permutation(n, key=...)``), as in the JAX learner. MLX's permutations differ from
JAX's for the same key; parity tests pass the JAX permutations in through ``update(..., perms=)``.

This module imports mlx and numpy (and the shim-written ``unilab_jax`` modules) only, never jax
or optax.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import mlx.core as mx
import numpy as np

from unilab_jax import xp as shim
from unilab_jax.algos.ppo import ppo
from unilab_jax.algos.ppo.ppo import TrainState
from unilab_jax.core import normalizer
from unilab_jax.fields import TRAJECTORY_FIELDS
from unilab_mlx import optim
from unilab_mlx.state import state_from_numpy, state_to_numpy

if TYPE_CHECKING:
    from tasks.base import TaskSpec

__all__ = ["TrainState", "Learner", "make_optimizer", "learning_rate", "make_learner", "state_from_numpy",
           "state_to_numpy"]

XP = shim.get("mlx")
BATCH_FIELDS = TRAJECTORY_FIELDS  # others (e.g. policy_version) are ignored


def make_optimizer(config: ppo.PPOConfig) -> optim.GradientTransformation:
    return optim.chain(optim.clip_by_global_norm(config.max_grad_norm),
                       optim.inject_hyperparams(optim.adam)(learning_rate=config.learning_rate))


def learning_rate(opt_state: Any) -> mx.array:
    """The injected (current, possibly KL-adapted) learning rate of a ``make_optimizer`` state."""
    return opt_state[1]["hyperparams"]["learning_rate"]


def _with_learning_rate(opt_state: Any, lr: mx.array) -> Any:
    inner = opt_state[1]
    hyper = {**inner["hyperparams"], "learning_rate": lr}
    return (opt_state[0], {**inner, "hyperparams": hyper}, *opt_state[2:])


def make_learner(algo: Any, config: ppo.PPOConfig, spec: TaskSpec) -> Learner:
    """The registry's factory for PPO and APPO (``algo.VTRACE``)."""
    return Learner(config, spec, use_vtrace=algo.VTRACE)


class Learner:
    """``learner_jax.Learner``'s interface and numbers on MLX (``use_vtrace=True``: APPO)."""

    def __init__(self, config: ppo.PPOConfig, spec: TaskSpec, use_vtrace: bool = False):
        self.config, self.spec, self.use_vtrace = config, spec, use_vtrace
        self.tx = make_optimizer(config)
        self._targets = mx.compile(self._targets_fn)
        self._step = mx.compile(self._step_fn)

    def init(self, key: mx.array | int) -> TrainState:
        if isinstance(key, int):
            key = mx.random.key(key)
        k_params, k_state = XP.random.split(key, 2)
        params = ppo.init_params(k_params, self.spec.obs_dim, self.spec.critic_obs_dim, self.spec.action_dim,
                                 self.config, XP)
        state = TrainState(params=params, opt_state=self.tx.init(params),
                           obs_norm=normalizer.stats_init(self.spec.obs_dim, XP),
                           critic_norm=normalizer.stats_init(self.spec.critic_obs_dim, XP),
                           key=k_state, updates=mx.array(0, dtype=mx.int32))
        mx.eval(state)
        return state

    @staticmethod
    def weights(state: TrainState) -> dict:
        return ppo.policy_weights(state.params, state.obs_norm)

    # -- compiled pieces ----------------------------------------------------------------------
    def _targets_fn(self, params: dict, obs_norm: Any, critic_norm: Any, batch: dict) -> tuple[dict, dict]:
        """Flattened [N, ...] minibatch source (with values/advantages/returns) and target metrics."""
        return ppo.minibatch_source(params, obs_norm, critic_norm, batch, self.config, self.use_vtrace)

    def _loss(self, params: dict, obs_norm: Any, critic_norm: Any, mb: dict) -> tuple[mx.array, dict]:
        return ppo.loss(params, obs_norm, critic_norm, mb, self.config, asymmetric_clip=self.use_vtrace)

    def _step_fn(self, params: dict, opt_state: Any, obs_norm: Any, critic_norm: Any, flat: dict,
                 idx: mx.array, fraction: mx.array) -> tuple[dict, Any, dict]:
        """One minibatch step: gather ``flat[idx]``, gradient, learning rate (KL rule or schedule at
        ``fraction``, written into the injected hyperparameter before the update, as in JAX), clipped Adam
        update, std bound."""
        cfg = self.config
        mb = {k: v[idx] for k, v in flat.items()}
        (_, metrics), grads = XP.value_and_grad(self._loss, has_aux=True)(params, obs_norm, critic_norm, mb)
        lr = ppo.scheduled_learning_rate(learning_rate(opt_state), metrics["kl"], fraction, cfg)
        opt_state = _with_learning_rate(opt_state, lr)
        updates, opt_state = self.tx.update(grads, opt_state, params)
        params = ppo.clamp_log_std(optim.apply_updates(params, updates), fraction, cfg)
        metrics = {**metrics, "learning_rate": lr, "grad_norm": optim.global_norm(grads),
                   "action_std": mx.mean(mx.exp(params["log_std"]))}
        return params, opt_state, metrics

    # -- the update ---------------------------------------------------------------------------
    def update(self, state: TrainState, batch: Mapping[str, Any],
               perms: Any = None) -> tuple[TrainState, dict]:
        """One PPO/APPO update on a [T, B] batch (dict of mx arrays; extra fields are ignored).

        ``perms`` (testing/parity only): optional [num_epochs, >= N] integer array replacing the
        minibatch permutations drawn from the state's key (the key still advances as usual), e.g.
        the JAX learner's ``jax.random.permutation(k, N)`` for each epoch key ``k``.
        Returns the new state and scalar metrics (means over all minibatch steps, plus
        ``value_mean`` and ``advantage_std`` of the targets).
        """
        cfg = self.config
        batch = {k: batch[k] for k in BATCH_FIELDS}
        t, b = batch["reward"].shape
        n = t * b
        mb_size = n // cfg.num_minibatches
        if mb_size == 0:
            raise ValueError(f"a batch of {n} transitions cannot make {cfg.num_minibatches} minibatches")
        used = mb_size * cfg.num_minibatches

        flat, target_metrics = self._targets(state.params, state.obs_norm, state.critic_norm, batch)
        keys = XP.random.split(state.key, cfg.num_epochs + 1)
        if perms is not None:
            perms = mx.array(np.ascontiguousarray(perms, dtype=np.int32))
            if perms.ndim != 2 or perms.shape[0] != cfg.num_epochs or perms.shape[1] < used:
                raise ValueError(f"perms must be [num_epochs={cfg.num_epochs}, >= {used}], got {perms.shape}")

        params, opt_state = state.params, state.opt_state
        fraction = ppo.schedule_fraction(state.updates, n, cfg)
        step_metrics: list[dict] = []
        for epoch in range(cfg.num_epochs):
            perm = perms[epoch] if perms is not None else mx.random.permutation(n, key=keys[epoch + 1])
            for i in range(cfg.num_minibatches):
                idx = perm[i * mb_size:(i + 1) * mb_size]
                params, opt_state, m = self._step(params, opt_state, state.obs_norm, state.critic_norm,
                                                  flat, idx, fraction)
                mx.eval(params, opt_state, m)  # one eval per compiled step
                step_metrics.append(m)

        metrics = {k: mx.mean(mx.stack([m[k] for m in step_metrics])) for k in step_metrics[0]}
        metrics.update(target_metrics)
        new_state = ppo.next_state(state, params, opt_state, batch, keys[0], cfg)
        mx.eval(new_state, metrics)
        return new_state, metrics
