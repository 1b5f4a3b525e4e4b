"""MLX learners for the off-policy algorithms (SAC, FastSAC, FlashSAC, RLPD, TD3), the same math as
``learner_jax`` (what does not depend on the platform is ``learner_common``'s, shared with it).

``SACFamilyLearner(algo, config, spec)`` and ``TD3Learner(config, spec)`` expose the JAX learners'
interface::

    learner = SACFamilyLearner(sac, config, spec)
    state = learner.init(mx.random.key(0))          # SACState of mx arrays
    state, metrics = learner.update(state, batch)    # batch: dict of arrays [U, B, ...]; {} is a no-op
    weights = learner.weights(state)

The losses are the algorithm modules' shim-written functions run on mlx arrays (``critic_loss``,
``actor_loss``, ``temperature_loss``, optional ``project_params`` and ``reward_scale``); the
optimizers are ``unilab_mlx.optim``'s optax twins built by the same ``learner_common.make_optimizer``
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
next state's key); SAC-family step ``i`` splits ``keys[i + 1]`` into ``(k_next, k_pi)`` (RLPD: and a
third key for its critic-subset uniforms ``u``; with images a last key for the DrQ offsets) and draws
``eps_next``/``eps`` ~ N(0, 1) of shape ``[B, noise_dim]``; TD3 draws ``eps_next`` from ``keys[i + 1]``.
MLX's normal draws differ from JAX's for the same key, so parity tests inject the JAX draws through
``update(..., noise={"eps_next": [U, B, N], "eps": [U, B, N]})`` with N the learner's ``noise_dim`` (the
action dimension; SAC Flow: its chain's) (RLPD: also ``"u"``; images: also ``"shift"``; TD3: ``eps_next`` only, N = A).

This module imports mlx and numpy (and the shim-written ``unilab_jax`` modules) only, never jax or
optax.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from types import ModuleType
from typing import Any

import mlx.core as mx
import numpy as np

from unilab_jax import xp as shim
from unilab_jax.algos.offpolicy import image_obs, td3
from unilab_jax.algos.offpolicy import learner_common as common
from unilab_jax.algos.offpolicy.sac import Norms, SACState
from unilab_jax.algos.offpolicy.td3 import TD3State
from unilab_jax.fields import REPLAY_FIELDS as BATCH_FIELDS
from unilab_mlx import optim
from unilab_mlx.state import state_from_numpy, state_to_numpy

__all__ = ["SACState", "TD3State", "SACFamilyLearner", "TD3Learner", "make_td3_learner", "state_from_numpy",
           "state_to_numpy", "BATCH_FIELDS"]

XP = shim.get("mlx")


def _python_cond(pred: bool, true_fn: Any, false_fn: Any, *operands: Any) -> Any:
    """``lax.cond`` for a predicate known when the step is traced (each compiled variant takes one branch)."""
    return true_fn(*operands) if pred else false_fn(*operands)


def _zero_actor_metrics(actor_step: Any, *operands: Any) -> dict:
    """A step that leaves the actor reports zeros for ``learner_common.ACTOR_METRICS``."""
    return {k: mx.array(0.0, dtype=mx.float32) for k in common.ACTOR_METRICS}


# How the MLX learners take gradients and apply updates (the steps' order is learner_common's).
OPS = common.Ops(value_and_grad=XP.value_and_grad, apply_updates=optim.apply_updates, global_norm=optim.global_norm,
                 cond=_python_cond, skip_metrics=_zero_actor_metrics)


def _as_key(key: Any) -> mx.array:
    if isinstance(key, int):
        return mx.random.key(key)
    return key if isinstance(key, mx.array) else mx.array(np.asarray(key, dtype=np.uint32))


def _prepare_batch(batch: Mapping[str, Any], fields: tuple[str, ...] = BATCH_FIELDS) -> dict:
    """``learner_common.prepare_batch`` of the fields as mx arrays."""
    return common.prepare_batch({k: batch[k] if isinstance(batch[k], mx.array) else mx.array(np.asarray(batch[k]))
                                 for k in fields if k in batch}, fields)


class _Compiled:
    """The MLX side of every off-policy learner: ``init`` (the state evaluated once)."""

    def init(self, key: Any) -> Any:
        key = _as_key(key)
        state = self.initial_state(self.init_params(np.asarray(key)), XP.random.split(key, 2)[1])
        mx.eval(state)
        return state


def _stack(step_metrics: list[dict]) -> dict:
    return {k: mx.stack([m[k] for m in step_metrics]) for k in step_metrics[0]}


def make_td3_learner(algo: ModuleType, config: td3.TD3Config, spec: Any) -> TD3Learner:
    """The registry's factory for TD3."""
    return TD3Learner(config, spec)


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


class SACFamilyLearner(_Compiled, common.SACFamilyBase):
    """Learner for SAC, FastSAC and FlashSAC (``algo`` is the algorithm module)."""

    def __init__(self, algo: ModuleType, config: Any, spec: Any):
        common.compute_dtype(config, "mlx")
        super().__init__(algo, config, spec, optim, XP)
        # With actor_every > 1, a critic-only variant for the steps that leave the actor (as TD3's delay).
        self._steps = {flag: mx.compile(functools.partial(self._step_fn, do_actor=flag))
                       for flag in ((True,) if self.actor_every == 1 else (False, True))}

    def _step_fn(self, nets_opt: tuple, norms: tuple, mb: dict, eps_next: mx.array,
                 eps: mx.array, do_actor: bool) -> tuple[tuple, dict]:
        """One gradient step (``learner_common.sac_step``: critics, [actor, temperature,] Polyak), pure in its
        arguments; ``nets_opt`` is a ``learner_common.SACNets`` as a tuple."""
        self.trace_count += 1
        nets, metrics = common.sac_step(self, OPS, common.SACNets(*nets_opt), Norms(*norms), self.augment(mb),
                                        eps_next, eps, do_actor)
        return tuple(nets), metrics

    def update(self, state: SACState, batch: Mapping[str, Any],
               noise: Mapping[str, Any] | None = None) -> tuple[SACState, dict]:
        """``batch`` [U, B, ...] -> (new state, metrics averaged over the U steps); ``{}`` is a no-op.

        ``noise`` (testing/parity only): ``{"eps_next": [U, B, N], "eps": [U, B, N]}`` (N = ``noise_dim``)
        replacing the standard-normal draws made from the state's key (the key still advances as usual);
        algorithms with a critic noise (RLPD) also take ``"u": [U, *critic_noise_shape]``, tasks with images
        ``"shift": [U, 2, B, 2]`` (the DrQ offsets).
        """
        if not batch:
            return state, {}
        batch = _prepare_batch(batch, self.batch_fields)
        state, norms = self.normalize(state, batch)
        norms = tuple(norms)

        n = batch["reward"].shape[0]
        _check_noise(noise, ("eps_next", "eps") + (() if self.critic_noise_shape is None else ("u",))
                     + (("shift",) if self.image_shape else ()), n)
        keys = XP.random.split(state.key, n + 1)
        step0 = int(state.steps.item()) if self.actor_every > 1 else 0  # the actor's schedule, read once per call
        carry = tuple(common.sac_nets(state))
        step_metrics = []
        for i in range(n):
            mb = {k: v[i] for k, v in batch.items()}
            shape = (int(mb["action"].shape[0]), self.noise_dim)
            ks = XP.random.split(keys[i + 1], self.step_keys)
            eps_next = _noise(noise, "eps_next", i, shape, ks[0])
            eps = _noise(noise, "eps", i, shape, ks[1])
            if self.critic_noise_shape is not None:
                u = (mx.array(np.asarray(noise["u"][i], np.float32)) if noise is not None
                     else mx.random.uniform(shape=self.critic_noise_shape, dtype=mx.float32, key=ks[2]))
                eps_next = (eps_next, u)
            if self.image_shape:
                mb[image_obs.SHIFT] = (mx.array(np.asarray(noise["shift"][i], np.int32)) if noise is not None
                                       else self.draw_shifts(ks[-1], shape[0]))
            do_actor = (step0 + i + 1) % self.actor_every == 0
            carry, m = self._steps[do_actor](carry, norms, mb, eps_next, eps)
            mx.eval(carry, m)  # one eval per compiled step
            step_metrics.append(m)
        metrics = self.call_metrics(_stack(step_metrics))
        metrics["reward_scale"] = norms[2]
        actor, critic, target_critic, actor_opt, critic_opt, log_alpha, alpha_opt, steps = carry
        new = state._replace(actor=actor, critic=critic, target_critic=target_critic, actor_opt=actor_opt,
                             critic_opt=critic_opt, log_alpha=log_alpha, alpha_opt=alpha_opt, steps=steps,
                             key=keys[0])
        mx.eval(new, metrics)
        return new, metrics


class TD3Learner(_Compiled, common.TD3Base):
    """Learner for TD3: delayed actor and target updates every ``policy_delay`` gradient steps."""

    def __init__(self, config: td3.TD3Config, spec: Any):
        common.compute_dtype(config, "mlx")
        super().__init__(config, spec, optim, XP)
        self._steps = {flag: mx.compile(functools.partial(self._step_fn, do_actor=flag)) for flag in (False, True)}

    def _step_fn(self, nets_opt: tuple, norms: tuple, mb: dict, eps_next: mx.array,
                 do_actor: bool) -> tuple[tuple, dict]:
        """One critic step, then (``do_actor``) the actor step and both Polyak updates (``learner_common.td3_step``);
        ``nets_opt`` is a ``learner_common.TD3Nets`` as a tuple."""
        self.trace_count += 1
        nets, metrics = common.td3_step(self, OPS, common.TD3Nets(*nets_opt), Norms(*norms), mb, eps_next, do_actor)
        return tuple(nets), metrics

    def update(self, state: TD3State, batch: Mapping[str, Any],
               noise: Mapping[str, Any] | None = None) -> tuple[TD3State, dict]:
        """``batch`` [U, B, ...] -> (new state, metrics averaged over the U steps); ``{}`` is a no-op.

        ``noise`` (testing/parity only): ``{"eps_next": [U, B, A]}`` replacing the target-smoothing
        draws made from the state's key (the key still advances as usual).
        """
        if not batch:
            return state, {}
        cfg = self.config
        batch = _prepare_batch(batch)
        state, norms = self.normalize(state, batch)
        norms = tuple(norms)

        n = batch["reward"].shape[0]
        _check_noise(noise, ("eps_next",), n)
        keys = XP.random.split(state.key, n + 1)
        step0 = int(state.steps.item())  # the delay schedule is decided on the host (one read per call)
        carry = tuple(common.td3_nets(state))
        step_metrics = []
        for i in range(n):
            mb = {k: v[i] for k, v in batch.items()}
            eps_next = _noise(noise, "eps_next", i, tuple(mb["action"].shape), keys[i + 1])
            # Fujimoto's schedule: the actor moves after every policy_delay-th critic step.
            do_actor = (step0 + i + 1) % cfg.policy_delay == 0
            carry, m = self._steps[do_actor](carry, norms, mb, eps_next)
            mx.eval(carry, m)  # one eval per compiled step
            step_metrics.append(m)
        metrics = common.td3_metrics(_stack(step_metrics))
        actor, critic, target_actor, target_critic, actor_opt, critic_opt, steps = carry
        new = state._replace(actor=actor, critic=critic, target_actor=target_actor, target_critic=target_critic,
                             actor_opt=actor_opt, critic_opt=critic_opt, steps=steps, key=keys[0])
        mx.eval(new, metrics)
        return new, metrics
