"""Soft actor-critic losses: twin critics, entropy-regularised actor, automatic temperature.

Shapes: every per-sample input is [B] (Q values, log probs of the tanh-Gaussian policy, rewards,
discounts ``gamma^n (1 - terminated)``); losses are scalars (means over B).
"""

from __future__ import annotations

from typing import Any

from unilab_jax import xp as shim


def sac_target(rewards: Any, discounts: Any, next_q1: Any, next_q2: Any, next_log_prob: Any,
               alpha: Any) -> Any:
    """Soft Bellman target ``r + discounts * (min(Q1', Q2') - alpha * log pi(a'|s'))``.

    rewards, discounts, next_q1, next_q2, next_log_prob: [B] (next_q* from the target critics at
    a' ~ pi(.|s')); alpha: scalar. Returns the gradient-stopped target [B].
    """
    xp = shim.namespace(rewards, discounts, next_q1, next_q2, next_log_prob, alpha)
    soft_v = xp.minimum(next_q1, next_q2) - alpha * next_log_prob
    return xp.stop_gradient(rewards + discounts * soft_v)


def sac_critic_loss(q1: Any, q2: Any, target_q: Any) -> Any:
    """Twin-critic loss ``mean((Q1 - y)^2) + mean((Q2 - y)^2)`` (CleanRL / Fujimoto convention, no 1/2).

    q1, q2: [B] online critics at the replayed actions; target_q: [B] (gradient stopped). Returns a
    scalar.
    """
    xp = shim.namespace(q1, q2, target_q)
    y = xp.stop_gradient(target_q)
    return xp.mean(xp.square(q1 - y)) + xp.mean(xp.square(q2 - y))


def sac_actor_loss(q1: Any, q2: Any, log_prob: Any, alpha: Any) -> Any:
    """Actor loss ``mean(alpha * log pi(a|s) - min(Q1, Q2)(s, a))`` with a ~ pi reparameterised.

    q1, q2, log_prob: [B]; alpha: scalar (treated as a constant: gradient stopped). Returns a scalar.
    """
    xp = shim.namespace(q1, q2, log_prob, alpha)
    alpha = xp.stop_gradient(xp.asarray(alpha, dtype=xp.float32))
    return xp.mean(alpha * log_prob - xp.minimum(q1, q2))


def sac_temperature_loss(log_alpha: Any, log_prob: Any, target_entropy: float) -> Any:
    """Temperature loss ``-mean(exp(log_alpha) * (log pi(a|s) + target_entropy))``; the log probs are
    gradient-stopped, so only ``log_alpha`` learns (alpha rises while the entropy is below target).

    log_alpha: scalar (differentiable); log_prob: [B]; target_entropy: python float (usually -|A|).
    Returns a scalar.
    """
    xp = shim.namespace(log_alpha, log_prob)
    return -xp.mean(xp.exp(log_alpha) * xp.stop_gradient(log_prob + target_entropy))
