"""V-trace off-policy targets (IMPALA) and the APPO loss (Sample Factory conventions)."""

from __future__ import annotations

from typing import Any

from unilab_jax import xp as shim
from unilab_jax.core.ppo_losses import standardize_advantages


def vtrace(values: Any, next_values: Any, rewards: Any, discounts: Any, log_rhos: Any, done: Any,
           lam: float = 1.0, clip_rho: float = 1.0, clip_pg_rho: float = 1.0) -> tuple[Any, Any]:
    """V-trace value targets and policy-gradient advantages over a time-major rollout.

    Args:
      values: [T, B] V(s_t) under the current critic.
      next_values: [T, B] V of the true successor of step t (the pre-reset final observation where
        the episode ended at t).
      rewards: [T, B].
      discounts: [T, B] ``gamma * (1 - terminated_t)`` (0 where the episode terminated).
      log_rhos: [T, B] ``log pi(a_t|s_t) - log mu(a_t|s_t)`` (target minus behaviour policy).
      done: [T, B] (bool or float) ``terminated | truncated``: cuts the trace; a truncated step still
        bootstraps from ``next_values`` through ``discounts``.
      lam: trace mixing lambda; clip_rho: rho-bar of the value targets; clip_pg_rho: the clip of
        the policy-gradient importance weight. The trace coefficient is ``c_t = lam * min(1, rho_t)``.

    Returns:
      ``(vs [T, B], pg_advantages [T, B])``, both gradient-stopped targets:
      ``vs_t = V(s_t) + sum_k (prod_{i<k} discounts_i (1 - done_i) c_i) rho'_k delta_k`` with
      ``delta_t = r_t + discounts_t next_values_t - V(s_t)``, ``rho' = min(clip_rho, rho)``, and
      ``pg_t = min(clip_pg_rho, rho_t) (r_t + discounts_t q_t - V(s_t))`` where the bootstrap
      ``q_t = lam vs_{t+1} + (1 - lam) V(s_{t+1})`` inside an episode and ``next_values_t`` where it
      ended (the same as rlax's ``vtrace_td_error_and_advantage``).
    """
    xp = shim.namespace(values, next_values, rewards, discounts, log_rhos, done)
    values = xp.stop_gradient(values)
    next_values = xp.stop_gradient(next_values)
    rhos = xp.exp(xp.stop_gradient(log_rhos))
    not_done = 1.0 - xp.astype(done, xp.float32)
    clipped_rhos = xp.minimum(rhos, xp.full_like(rhos, clip_rho))
    trace = discounts * not_done * (lam * xp.minimum(rhos, xp.ones_like(rhos)))
    td = clipped_rhos * (rewards + discounts * next_values - values)

    def step(acc_next: Any, xs: tuple[Any, Any, Any]) -> tuple[Any, tuple[Any, Any]]:
        td_t, trace_t, nd_t = xs
        acc = td_t + trace_t * acc_next
        # vs_{t+1} - V(s_{t+1}) seen from step t: zero across an episode boundary.
        return acc, (acc, nd_t * acc_next)

    _, (acc, acc_next) = xp.scan(step, xp.zeros_like(td[0, ...]), (td, trace, not_done), reverse=True)
    vs = values + acc
    q_bootstrap = next_values + lam * acc_next
    pg_rhos = xp.minimum(rhos, xp.full_like(rhos, clip_pg_rho))
    pg_advantages = pg_rhos * (rewards + discounts * q_bootstrap - values)
    return xp.stop_gradient(vs), xp.stop_gradient(pg_advantages)


def appo_loss(new_log_prob: Any, behaviour_log_prob: Any, pg_advantages: Any, new_values: Any, vs: Any,
              entropy: Any, clip_eps: float, vf_coef: float, ent_coef: float,
              normalize_advantages: bool = True) -> tuple[Any, dict[str, Any]]:
    """APPO objective to minimise: PPO's clipped surrogate with Sample Factory's asymmetric ratio clip
    ``[1 / (1 + clip_eps), 1 + clip_eps]`` on V-trace advantages, plus a squared error to ``vs``.

    Args:
      new_log_prob: [N] current policy log probs (differentiable).
      behaviour_log_prob: [N] log probs of the policy that acted (possibly several versions old).
      pg_advantages: [N] from ``vtrace`` (normalised over the minibatch if ``normalize_advantages``).
      new_values: [N] current critic (differentiable). vs: [N] V-trace value targets.
      entropy: [N] per-sample policy entropy.

    Returns:
      ``(loss, metrics)``: ``loss = policy_loss + vf_coef * mean((v - vs)^2) - ent_coef * mean(H)``
      and scalars ``policy_loss``, ``value_loss``, ``entropy``, ``approx_kl``, ``clip_fraction``
      (fraction of ratios outside the clip range).
    """
    xp = shim.namespace(new_log_prob, behaviour_log_prob, pg_advantages, new_values, vs, entropy)
    adv = xp.stop_gradient(pg_advantages)
    if normalize_advantages:
        adv = standardize_advantages(xp, adv)
    high = 1.0 + clip_eps
    low = 1.0 / high
    log_ratio = new_log_prob - behaviour_log_prob
    ratio = xp.exp(log_ratio)
    policy_loss = -xp.mean(xp.minimum(ratio * adv, xp.clip(ratio, low, high) * adv))
    value_loss = xp.mean(xp.square(new_values - xp.stop_gradient(vs)))
    entropy_mean = xp.mean(entropy)
    loss = policy_loss + vf_coef * value_loss - ent_coef * entropy_mean

    sg_ratio = xp.stop_gradient(ratio)
    outside = (sg_ratio > high) | (sg_ratio < low)
    metrics = {
        "policy_loss": xp.stop_gradient(policy_loss),
        "value_loss": xp.stop_gradient(value_loss),
        "entropy": xp.stop_gradient(entropy_mean),
        "approx_kl": xp.mean((sg_ratio - 1.0) - xp.stop_gradient(log_ratio)),
        "clip_fraction": xp.mean(xp.astype(outside, xp.float32)),
    }
    return loss, metrics
