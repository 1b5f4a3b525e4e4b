"""Diagonal Gaussian and tanh-squashed Gaussian policies.

Shapes: ``mean``, ``log_std``, ``x``, ``eps`` are ``[..., A]`` (``log_std`` may also be ``[A]`` and
broadcast); every log-probability, entropy and KL is summed over the last (action) axis and has the
leading shape ``[...]``.
"""

from __future__ import annotations

import math
from typing import Any

from unilab_jax import xp as shim

_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
_LOG2 = math.log(2.0)


def gaussian_log_prob(x: Any, mean: Any, log_std: Any) -> Any:
    """Log density of ``x`` under N(mean, exp(log_std)^2), summed over the last axis.

    x, mean: [..., A]; log_std: [..., A] or [A]. Returns [...].
    """
    xp = shim.namespace(x, mean, log_std)
    z = (x - mean) * xp.exp(-log_std)
    return xp.sum(-0.5 * xp.square(z) - log_std - _HALF_LOG_2PI, axis=-1)


def gaussian_entropy(log_std: Any) -> Any:
    """Entropy of a diagonal Gaussian, summed over the last axis.

    log_std: [..., A] (or [A]). Returns log_std's leading shape [...] (a scalar for [A]); broadcasting
    to a batch is the caller's job.
    """
    xp = shim.namespace(log_std)
    return xp.sum(log_std + (0.5 + _HALF_LOG_2PI), axis=-1)


def gaussian_kl(mean_p: Any, log_std_p: Any, mean_q: Any, log_std_q: Any) -> Any:
    """KL(p || q) between diagonal Gaussians, summed over the last axis.

    All inputs broadcast to [..., A]. Returns [...].
    """
    xp = shim.namespace(mean_p, log_std_p, mean_q, log_std_q)
    var_ratio = xp.exp(2.0 * (log_std_p - log_std_q))
    mahal = xp.square((mean_p - mean_q) * xp.exp(-log_std_q))
    return xp.sum(log_std_q - log_std_p + 0.5 * (var_ratio + mahal - 1.0), axis=-1)


def tanh_log_det_jacobian(pre_tanh: Any) -> Any:
    """log |d tanh(u)/du| summed over the last axis, computed stably as 2 (log 2 - u - softplus(-2u)).

    pre_tanh: [..., A]. Returns [...].
    """
    xp = shim.namespace(pre_tanh)
    return xp.sum(2.0 * (_LOG2 - pre_tanh - xp.softplus(-2.0 * pre_tanh)), axis=-1)


def tanh_gaussian_sample(mean: Any, log_std: Any, eps: Any) -> tuple[Any, Any]:
    """Reparameterised sample of tanh(N(mean, std^2)) and its log probability.

    mean, eps: [..., A]; log_std: [..., A] or [A]; eps is standard normal noise drawn by the caller.
    Returns ``(action [..., A], log_prob [...])`` with ``action = tanh(mean + exp(log_std) * eps)``
    and ``log_prob`` the density of ``action`` (Gaussian log-density minus the tanh log-Jacobian).
    Gradients flow to ``mean`` and ``log_std`` through the sample.
    """
    xp = shim.namespace(mean, log_std, eps)
    u = mean + xp.exp(log_std) * eps
    # (u - mean) / std == eps exactly, so the Gaussian term is written with eps directly.
    gauss = xp.sum(-0.5 * xp.square(eps) - log_std - _HALF_LOG_2PI, axis=-1)
    return xp.tanh(u), gauss - tanh_log_det_jacobian(u)


def tanh_gaussian_log_prob(pre_tanh: Any, mean: Any, log_std: Any) -> Any:
    """Log density of ``tanh(pre_tanh)`` under the tanh-squashed Gaussian.

    Takes the pre-squash value (atanh of a saturated action is ill-conditioned, so store ``u``).
    pre_tanh, mean: [..., A]; log_std: [..., A] or [A]. Returns [...].
    """
    return gaussian_log_prob(pre_tanh, mean, log_std) - tanh_log_det_jacobian(pre_tanh)


def tanh_gaussian_entropy_estimate(mean: Any, log_std: Any, eps: Any) -> Any:
    """Single-sample entropy estimate of the tanh-squashed Gaussian: ``-log_prob`` of the sample
    ``tanh(mean + std * eps)`` (it has no closed form).

    mean, eps: [..., A]; log_std: [..., A] or [A]. Returns [...].
    """
    return -tanh_gaussian_sample(mean, log_std, eps)[1]
