"""PPO losses (rsl_rl conventions) and the KL-adaptive learning-rate rule."""

from __future__ import annotations

from typing import Any

from unilab_jax import xp as shim


def standardize_advantages(xp: shim.Backend, adv: Any, eps: float = 1e-8) -> Any:
    """(adv - mean) / (std + eps) over all elements, std with Bessel's correction (torch's default,
    as in rsl_rl and CleanRL). adv: [N] (any shape). Returns adv's shape."""
    n = 1
    for d in adv.shape:
        n *= int(d)
    mean = xp.mean(adv)
    var = xp.sum(xp.square(adv - mean)) / float(max(n - 1, 1))
    return (adv - mean) / (xp.sqrt(var) + eps)


def ppo_loss(new_log_prob: Any, old_log_prob: Any, advantages: Any, new_values: Any, old_values: Any,
             returns: Any, entropy: Any, clip_eps: float, value_clip: float | None, vf_coef: float,
             ent_coef: float, normalize_advantages: bool = True) -> tuple[Any, dict[str, Any]]:
    """The PPO objective to minimise, as in rsl_rl.

    Args:
      new_log_prob: [N] log pi_theta(a|s) of the current policy (differentiable).
      old_log_prob: [N] log prob under the policy that collected the data.
      advantages: [N] (GAE) advantages; normalised over the minibatch when ``normalize_advantages``.
      new_values: [N] V_theta(s) (differentiable). old_values: [N] values at collection time.
      returns: [N] value targets (advantages + old values).
      entropy: [N] per-sample policy entropy (differentiable).
      clip_eps: ratio clip epsilon. value_clip: None for the plain squared error, or the clip range
        of the rsl_rl clipped value loss ``max((v - R)^2, (v_old + clip(v - v_old, -c, c) - R)^2)``.
      vf_coef, ent_coef: loss weights.

    Returns:
      ``(loss, metrics)``: ``loss = policy_loss + vf_coef * value_loss - ent_coef * mean(entropy)``
      (scalar) and ``metrics`` with scalars ``policy_loss``, ``value_loss``, ``entropy``,
      ``approx_kl`` (mean of ``(r - 1) - log r``, a non-negative estimate of KL(old || new)) and
      ``clip_fraction`` (fraction of |r - 1| > clip_eps). The value loss has no 1/2 factor.
    """
    xp = shim.namespace(new_log_prob, old_log_prob, advantages, new_values, old_values, returns, entropy)
    adv = xp.stop_gradient(advantages)
    if normalize_advantages:
        adv = standardize_advantages(xp, adv)
    log_ratio = new_log_prob - old_log_prob
    ratio = xp.exp(log_ratio)
    surrogate = ratio * adv
    surrogate_clipped = xp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps) * adv
    policy_loss = -xp.mean(xp.minimum(surrogate, surrogate_clipped))

    returns = xp.stop_gradient(returns)
    value_loss_sq = xp.square(new_values - returns)
    if value_clip is not None:
        clipped = old_values + xp.clip(new_values - old_values, -value_clip, value_clip)
        value_loss_sq = xp.maximum(value_loss_sq, xp.square(clipped - returns))
    value_loss = xp.mean(value_loss_sq)
    entropy_mean = xp.mean(entropy)
    loss = policy_loss + vf_coef * value_loss - ent_coef * entropy_mean

    sg_log_ratio = xp.stop_gradient(log_ratio)
    sg_ratio = xp.stop_gradient(ratio)
    metrics = {
        "policy_loss": xp.stop_gradient(policy_loss),
        "value_loss": xp.stop_gradient(value_loss),
        "entropy": xp.stop_gradient(entropy_mean),
        "approx_kl": xp.mean((sg_ratio - 1.0) - sg_log_ratio),
        "clip_fraction": xp.mean(xp.astype(xp.abs(sg_ratio - 1.0) > clip_eps, xp.float32)),
    }
    return loss, metrics


def kl_adaptive_lr(lr: Any, kl: Any, desired_kl: float, factor: float = 1.5, min_lr: float = 1e-5,
                   max_lr: float = 1e-2) -> Any:
    """rsl_rl's adaptive learning rate: ``kl > 2 desired -> max(min_lr, lr / factor)``;
    ``0 < kl < desired / 2 -> min(max_lr, lr * factor)``; otherwise unchanged.

    lr, kl: scalars (python floats or 0-d arrays, traceable under jit). Returns a float32 0-d array.
    """
    xp = shim.namespace(lr, kl)
    lr = xp.asarray(lr, dtype=xp.float32)
    kl = xp.asarray(kl, dtype=xp.float32)
    lower = xp.maximum(lr / factor, xp.full_like(lr, min_lr))
    higher = xp.minimum(lr * factor, xp.full_like(lr, max_lr))
    out = xp.where(kl > 2.0 * desired_kl, lower, lr)
    return xp.where((kl > 0.0) & (kl < 0.5 * desired_kl), higher, out)
