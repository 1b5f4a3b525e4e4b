"""Generalized advantage estimation with termination and truncation kept apart."""

from __future__ import annotations

from typing import Any

from unilab_jax import xp as shim


def gae(rewards: Any, values: Any, next_values: Any, terminated: Any, truncated: Any,
        gamma: float, lam: float) -> tuple[Any, Any]:
    """GAE(gamma, lambda) advantages and lambda-returns over a time-major rollout.

    Args:
      rewards: [T, B] reward of step t.
      values: [T, B] V(s_t).
      next_values: [T, B] V of the TRUE successor of step t: V(s_{t+1}) inside an episode and the
        value of the pre-reset final observation where the episode ended at t.
      terminated: [T, B] (bool or float) the episode ended in a terminal state at t: no bootstrap.
      truncated: [T, B] (bool or float) the episode was cut (time limit) at t: bootstrap from
        ``next_values`` but cut the trace.
      gamma, lam: discount and GAE lambda (python floats or scalars).

    Returns:
      ``(advantages [T, B], returns [T, B])`` with
      ``delta_t = r_t + gamma (1 - terminated_t) next_values_t - values_t``,
      ``A_t = delta_t + gamma lam (1 - done_t) A_{t+1}`` (``done = terminated | truncated``,
      ``A_T = 0``) and ``returns = A + values``. No gradient is stopped: call it on data.
    """
    xp = shim.namespace(rewards, values, next_values, terminated, truncated)
    term = xp.astype(terminated, xp.float32)
    trunc = xp.astype(truncated, xp.float32)
    not_done = (1.0 - term) * (1.0 - trunc)  # 1 - (terminated | truncated) for 0/1 inputs
    deltas = rewards + gamma * (1.0 - term) * next_values - values
    trace = (gamma * lam) * not_done

    def step(adv_next: Any, xs: tuple[Any, Any]) -> tuple[Any, Any]:
        delta, tr = xs
        adv = delta + tr * adv_next
        return adv, adv

    _, advantages = xp.scan(step, xp.zeros_like(deltas[0, ...]), (deltas, trace), reverse=True)
    return advantages, advantages + values
