"""JAX learner for PPO and APPO: one jitted update, scans over epochs and minibatches inside."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import optax

from tasks.base import TaskSpec
from unilab_jax import xp as shim
from unilab_jax.algos.ppo import ppo
from unilab_jax.algos.ppo.ppo import TrainState
from unilab_jax.core import normalizer

XP = shim.get("jax")
# The update donates its input state on accelerators (measured on the H100: FastSAC 28.5 -> 27.4 ms per
# call, FlashSAC 13.8 -> 12.8) but not on the CPU, where an update can take minutes and a stopped run
# must still save the state it had before the update in flight (unilab_jax/training/trainer.py, LearnerThread).
DONATE_STATE = 0 if jax.default_backend() != "cpu" else ()
def make_optimizer(config: ppo.PPOConfig) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(config.max_grad_norm),
                       optax.inject_hyperparams(optax.adam)(learning_rate=config.learning_rate))


def learning_rate(opt_state: Any) -> jax.Array:
    return opt_state[1].hyperparams["learning_rate"]


def _with_learning_rate(opt_state: Any, lr: jax.Array) -> Any:
    inner = opt_state[1]
    hyper = {**inner.hyperparams, "learning_rate": lr}
    return (opt_state[0], inner._replace(hyperparams=hyper), *opt_state[2:])


def make_learner(algo: Any, config: ppo.PPOConfig, spec: TaskSpec) -> Learner:
    """The registry's factory for PPO and APPO (``algo.VTRACE``)."""
    return Learner(config, spec, use_vtrace=algo.VTRACE)


class Learner:
    """``init(key) -> TrainState``; ``update(state, batch) -> (state, metrics)``; ``weights(state)``.

    ``vtrace=True`` gives APPO: advantages and value targets come from V-trace with importance
    ratios between the current policy and the (possibly stale) behaviour policy, and the policy
    loss uses the asymmetric clip [1/(1+eps), 1+eps].

    PPO variants subclass it and override the hooks, keeping the update itself (targets, epochs,
    minibatches, KL-adaptive learning rate, normalizers) in one place: ``init_params``,
    ``init_opt_state``, ``actor`` (what the policy sees), ``loss`` (e.g. plus an auxiliary loss),
    ``apply_gradients`` (e.g. a second optimizer), ``extra_fields`` (batch fields the loss needs
    besides PPO's) and ``weights``. ``compiler_options`` go to the update's ``jax.jit`` (as the off-policy
    learners'; e.g. XLA's fast-compile options for tests).
    """

    extra_fields: tuple[str, ...] = ()
    actor = staticmethod(ppo._actor)

    def __init__(self, config: ppo.PPOConfig, spec: TaskSpec, use_vtrace: bool = False,
                 compiler_options: dict | None = None):
        self.config, self.spec, self.use_vtrace = config, spec, use_vtrace
        self.tx = make_optimizer(config)
        self.update = jax.jit(self.traced_update, donate_argnums=DONATE_STATE, compiler_options=compiler_options)

    def traced_update(self, state: Any, batch: dict) -> tuple[Any, dict]:
        """The pure update as this learner compiles it (float32 throughout; ``training.sharding`` compiles this
        same function over several devices)."""
        return self._update(state, batch)

    def init_params(self, key: jax.Array) -> dict:
        return ppo.init_params(key, self.spec.obs_dim, self.spec.critic_obs_dim, self.spec.action_dim,
                               self.config, XP)

    def init_opt_state(self, params: dict) -> Any:
        return self.tx.init(params)

    def init(self, key: jax.Array) -> TrainState:
        k_params, k_state = jax.random.split(key)
        params = self.init_params(k_params)
        return TrainState(params=params, opt_state=self.init_opt_state(params),
                          obs_norm=normalizer.stats_init(self.spec.obs_dim, XP),
                          critic_norm=normalizer.stats_init(self.spec.critic_obs_dim, XP),
                          key=k_state, updates=jnp.zeros((), jnp.int32))

    @staticmethod
    def weights(state: TrainState) -> dict:
        return ppo.policy_weights(state.params, state.obs_norm)

    def loss(self, params: dict, obs_norm: Any, critic_norm: Any, mb: dict) -> tuple[jax.Array, dict]:
        return ppo.loss(params, obs_norm, critic_norm, mb, self.config, asymmetric_clip=self.use_vtrace,
                        actor=self.actor)

    def apply_gradients(self, params: dict, opt_state: Any, grads: dict, metrics: dict,
                        fraction: jax.Array) -> tuple[dict, Any, Any]:
        """One optimizer step at schedule position ``fraction`` (``ppo.schedule_fraction``): the learning rate
        (KL rule or schedule), then the std bound; returns (params, opt_state, learning rate used)."""
        lr = ppo.scheduled_learning_rate(learning_rate(opt_state), metrics["kl"], fraction, self.config)
        opt_state = _with_learning_rate(opt_state, lr)
        updates, opt_state = self.tx.update(grads, opt_state, params)
        return ppo.clamp_log_std(optax.apply_updates(params, updates), fraction, self.config), opt_state, lr

    # -- the update ---------------------------------------------------------------------------
    def _update(self, state: TrainState, batch: dict) -> tuple[TrainState, dict]:
        cfg = self.config
        flat, target_metrics = ppo.minibatch_source(state.params, state.obs_norm, state.critic_norm, batch, cfg,
                                                    self.use_vtrace, actor=self.actor, extra_fields=self.extra_fields)
        n = batch["reward"].size
        mb_size = n // cfg.num_minibatches
        fraction = ppo.schedule_fraction(state.updates, n, cfg)

        def loss_fn(params: dict, mb: dict) -> tuple[jax.Array, dict]:
            return self.loss(params, state.obs_norm, state.critic_norm, mb)

        grad_fn = jax.value_and_grad(loss_fn, has_aux=True)

        def minibatch_step(carry: tuple, mb: dict) -> tuple[tuple, dict]:
            params, opt_state = carry
            (_, metrics), grads = grad_fn(params, mb)
            params, opt_state, lr = self.apply_gradients(params, opt_state, grads, metrics, fraction)
            grad_norm = jnp.sqrt(sum(jnp.sum(jnp.square(g)) for g in jax.tree_util.tree_leaves(grads)))
            metrics = {**metrics, "learning_rate": lr, "grad_norm": grad_norm,
                       "action_std": jnp.mean(jnp.exp(params["log_std"]))}
            return (params, opt_state), metrics

        def epoch(carry: tuple, key: jax.Array) -> tuple[tuple, dict]:
            perm = jax.random.permutation(key, n)[: mb_size * cfg.num_minibatches]
            mbs = jax.tree_util.tree_map(
                lambda x: x[perm].reshape(cfg.num_minibatches, mb_size, *x.shape[1:]), flat)
            return jax.lax.scan(minibatch_step, carry, mbs)

        keys = jax.random.split(state.key, cfg.num_epochs + 1)
        (params, opt_state), metrics = jax.lax.scan(epoch, (state.params, state.opt_state), keys[1:])
        metrics = {**jax.tree_util.tree_map(jnp.mean, metrics), **target_metrics}
        return ppo.next_state(state, params, opt_state, batch, keys[0], cfg), metrics
