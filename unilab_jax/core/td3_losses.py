"""TD3: target policy smoothing, clipped double-Q target, twin-critic and deterministic actor losses.

Shapes: actions [B, A]; everything per-sample is [B]; losses are scalars.
"""

from __future__ import annotations

from typing import Any

from unilab_jax import xp as shim


def td3_target_action(next_mean_action: Any, noise: Any, noise_clip: float, act_limit: float = 1.0) -> Any:
    """Target policy smoothing: ``clip(mu'(s') + clip(noise, -noise_clip, noise_clip), -act_limit,
    act_limit)``.

    next_mean_action: [B, A] target actor output; noise: [B, A] already scaled by the policy noise
    std (``policy_noise * eps``, drawn by the caller). Returns [B, A].
    """
    xp = shim.namespace(next_mean_action, noise)
    smoothed = next_mean_action + xp.clip(noise, -noise_clip, noise_clip)
    return xp.clip(smoothed, -act_limit, act_limit)


def td3_target(rewards: Any, discounts: Any, next_q1: Any, next_q2: Any) -> Any:
    """Clipped double-Q target ``r + discounts * min(Q1', Q2')``.

    All [B] (discounts = gamma^n (1 - terminated)). Returns the gradient-stopped target [B].
    """
    xp = shim.namespace(rewards, discounts, next_q1, next_q2)
    return xp.stop_gradient(rewards + discounts * xp.minimum(next_q1, next_q2))


def td3_critic_loss(q1: Any, q2: Any, target: Any) -> Any:
    """``mean((Q1 - y)^2) + mean((Q2 - y)^2)`` (Fujimoto et al.). q1, q2, target: [B]. Returns a scalar."""
    xp = shim.namespace(q1, q2, target)
    y = xp.stop_gradient(target)
    return xp.mean(xp.square(q1 - y)) + xp.mean(xp.square(q2 - y))


def td3_actor_loss(q1: Any) -> Any:
    """Deterministic policy gradient loss ``-mean(Q1(s, mu(s)))``. q1: [B]. Returns a scalar."""
    xp = shim.namespace(q1)
    return -xp.mean(q1)
