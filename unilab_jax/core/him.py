"""HIM (Long et al., arXiv 2312.11460): the hybrid internal model's estimator losses.

A history encoder outputs a base-velocity estimate and a latent; the latent is trained by a
swapped-prediction contrastive loss against a target encoder of the successor's privileged state,
with soft prototype assignments balanced by Sinkhorn-Knopp iterations (SwAV, Caron et al. 2020),
and the velocity by regression. Shapes: batch B, latent L, prototypes K.
"""

from __future__ import annotations

import math
from typing import Any

from unilab_jax import xp as shim


def l2_normalize(x: Any, eps: float = 1e-12) -> Any:
    """``x / max(||x||_2, eps)`` along the last axis (torch's ``F.normalize``). x: [..., L]."""
    xp = shim.namespace(x)
    norm = xp.sqrt(xp.sum(xp.square(x), axis=-1, keepdims=True))
    return x / xp.maximum(norm, xp.full_like(norm, eps))


def sinkhorn(scores: Any, n_iters: int = 3, eps: float = 0.05) -> Any:
    """Balanced soft assignments of B samples to K prototypes (SwAV's Sinkhorn-Knopp).

    Starts from ``exp(scores / eps)`` normalised to total mass 1 and alternates: rescale each
    prototype's column to mass 1/K (equipartition: every prototype gets the same share of the
    batch), then each sample's row to mass 1/B. Returns ``Q * B``, [B, K]: each row is a probability
    vector over prototypes (sums to 1 exactly, the last step is the row one) and each column sums to
    about B/K (exactly in the limit of many iterations). Computed in the log domain, which is the
    same map without overflow for large ``scores / eps``.

    scores: [B, K] (e.g. cosine similarities of latents and prototypes); n_iters >= 1 (HIMLoco and
    SwAV use 3); eps: entropic temperature (0.05). No gradient flows through the result.
    """
    xp = shim.namespace(scores)
    b, k = int(scores.shape[0]), int(scores.shape[1])
    log_q = xp.stop_gradient(scores) / eps
    log_q = log_q - xp.logsumexp(xp.reshape(log_q, (b * k,)), axis=0)
    for _ in range(n_iters):
        log_q = log_q - (xp.logsumexp(log_q, axis=0, keepdims=True) + math.log(k))
        log_q = log_q - (xp.logsumexp(log_q, axis=1, keepdims=True) + math.log(b))
    return xp.stop_gradient(xp.exp(log_q + math.log(b)))


def swapped_prediction_loss(z_source: Any, z_target: Any, prototypes: Any, temperature: float = 3.0,
                            n_iters: int = 3, eps: float = 0.05) -> tuple[Any, dict[str, Any]]:
    """Swapped prediction: each view predicts the other view's Sinkhorn code.

    z_source: [B, L] history-encoder latents; z_target: [B, L] target-encoder latents of the
    successor's privileged state (both unit-norm); prototypes: [K, L] (unit-norm). With scores
    ``s = z @ prototypes^T`` [B, K], codes ``q = sinkhorn(s)`` (no gradient) and predictions
    ``log p = log_softmax(s / temperature)``::

        loss = -0.5 * mean_{b,k}(q_source * log p_target + q_target * log p_source)

    The mean runs over samples *and* prototypes, as HIMLoco's implementation does (a per-sample
    cross-entropy divided by K). Returns ``(loss, metrics)``: ``swap_loss`` and
    ``prototype_usage`` (fraction of the K prototypes that are some sample's arg-max code).
    """
    xp = shim.namespace(z_source, z_target, prototypes)
    scores_s = xp.matmul(z_source, prototypes.T)
    scores_t = xp.matmul(z_target, prototypes.T)
    q_s = sinkhorn(scores_s, n_iters, eps)
    q_t = sinkhorn(scores_t, n_iters, eps)
    log_p_s = xp.log_softmax(scores_s / temperature, axis=-1)
    log_p_t = xp.log_softmax(scores_t / temperature, axis=-1)
    loss = -0.5 * xp.mean(q_s * log_p_t + q_t * log_p_s)
    k = int(prototypes.shape[0])
    hits = xp.max(xp.one_hot(xp.argmax(q_s, axis=-1), k), axis=0)
    metrics = {"swap_loss": xp.stop_gradient(loss), "prototype_usage": xp.mean(xp.stop_gradient(hits))}
    return loss, metrics


def velocity_loss(v_pred: Any, v_target: Any) -> Any:
    """Velocity regression ``mean((v_pred - v_target)^2)`` over every element (target gradient-stopped).

    v_pred, v_target: [B, V]. Returns a scalar.
    """
    xp = shim.namespace(v_pred, v_target)
    return xp.mean(xp.square(v_pred - xp.stop_gradient(v_target)))
