"""Flow policies as a chain of Gaussians (SAC Flow's noise-augmented, gated Euler rollout).

A flow policy turns noise into an action by integrating a velocity field ``v(a, t, s)`` over K Euler
steps of size ``dt = 1 / K`` at times ``t_k = k / K``. With Gaussian noise added at every step the
rollout is a Markov chain of Gaussians::

    a_0 ~ N(0, I)
    a_{k+1} = a_k + dt * v(a_k, t_k, s) + std(s) * eps_k,      eps_k ~ N(0, I),  k = 0..K-1
    action = tanh(a_K)

so the joint log-density of the chain is the sum of K + 1 Gaussian log-densities, and with the tanh
log-Jacobian of the last step it is the log-probability SAC's entropy term uses. The velocity is
gated like a GRU's update (SAC Flow's "Flow-G"): ``v = sigmoid(g) * (c - a_k)`` with a candidate ``c``
and a gate logit ``g`` from one network, so each step is the convex mix
``a_k + dt * z * (c - a_k) = (1 - dt z) a_k + dt z c`` and gradients through the K steps neither
explode nor vanish with K (``|d a_{k+1} / d a_k| <= 1`` through the direct path).

Shapes: ``a``, ``candidate``, ``gate_logit`` ``[B, A]``; ``noise`` ``[B, (K + 1) A]`` (columns
``[0, A)`` are ``a_0``, then one block of A per step); ``log_std`` ``[B, A]``; log-probabilities ``[B]``.
Randomness enters only as ``noise`` (drawn by the caller).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from unilab_jax import xp as shim
from unilab_jax.core import distributions

_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


def sigmoid(x: Any) -> Any:
    """Logistic function ``1 / (1 + exp(-x))`` on any backend, from ``z = exp(-|x|)`` (never overflows):
    ``1 / (1 + z)`` for x >= 0, ``z / (1 + z)`` below. Same values, and a gradient that stays finite for any
    logit: the plain quotient's is inf / inf = NaN in float32 once ``exp(-x)`` overflows (x below about -89),
    which is how a drifting gate logit turned SAC Flow's weights NaN."""
    xp = shim.namespace(x)
    z = xp.exp(-xp.abs(x))
    return xp.where(x >= 0, 1.0 / (1.0 + z), z / (1.0 + z))


def gated_velocity(a: Any, candidate: Any, gate_logit: Any) -> Any:
    """Flow-G velocity ``sigmoid(gate_logit) * (candidate - a)``: [B, A] each -> [B, A]."""
    return sigmoid(gate_logit) * (candidate - a)


def standard_log_prob(eps: Any) -> Any:
    """Log-density of ``eps`` [B, A] under N(0, I), summed over the last axis -> [B]."""
    xp = shim.namespace(eps)
    return xp.sum(-0.5 * xp.square(eps) - _HALF_LOG_2PI, axis=-1)


def flow_rollout(velocity: Callable[[Any, int], Any], noise: Any, log_std: Any, num_steps: int,
                 deterministic: bool = False) -> tuple[Any, Any]:
    """The K-step noisy Euler chain and its log-density.

    ``velocity(a [B, A], k) -> [B, A]`` (``k`` the step's index, its time ``t_k = k / K``); ``noise``
    ``[B, (K + 1) A]`` standard normal; ``log_std`` ``[B, A]`` (the per-step noise scale, the same at
    every step). Returns ``(a_K [B, A], log_prob [B])`` with
    ``log_prob = log N(a_0; 0, I) + sum_k log N(a_{k+1}; a_k + dt v_k, std^2)``. Deterministic: ``a_0 = 0``,
    no step noise, ``log_prob`` 0 (``noise`` is not read; its shape may differ).
    """
    xp = shim.namespace(log_std)
    dt = 1.0 / num_steps
    a_dim = int(log_std.shape[-1])
    if deterministic:
        a = xp.zeros(tuple(log_std.shape), dtype=xp.float32)
        for k in range(num_steps):
            a = a + dt * velocity(a, k)
        return a, xp.zeros(tuple(log_std.shape[:-1]), dtype=xp.float32)
    if int(noise.shape[-1]) != (num_steps + 1) * a_dim:
        raise ValueError(f"noise has {noise.shape[-1]} columns; {num_steps + 1} x {a_dim} expected")
    std = xp.exp(log_std)
    a = noise[..., :a_dim]
    log_prob = standard_log_prob(a)
    step_norm = xp.sum(-log_std - _HALF_LOG_2PI, axis=-1)  # the std term of each step's Gaussian
    for k in range(num_steps):
        eps = noise[..., (k + 1) * a_dim:(k + 2) * a_dim]
        a = a + dt * velocity(a, k) + std * eps
        # (a_{k+1} - mean_k) / std == eps exactly, so each step's density is written with eps.
        log_prob = log_prob + xp.sum(-0.5 * xp.square(eps), axis=-1) + step_norm
    return a, log_prob


def squash(pre_tanh: Any, log_prob: Any) -> tuple[Any, Any]:
    """``(tanh(a_K), log_prob - log|d tanh / d a_K|)``: the action in (-1, 1) and its log-probability."""
    xp = shim.namespace(pre_tanh)
    return xp.tanh(pre_tanh), log_prob - distributions.tanh_log_det_jacobian(pre_tanh)
