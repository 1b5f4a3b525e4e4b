"""HORA (Qi et al., arXiv 2210.04887) distillation: the student's adaptation-module regression loss.

Stage 1 trains a teacher whose policy sees ``z = tanh(mlp(extrinsics))``; stage 2 trains an
adaptation module that predicts ``z`` from proprioceptive history alone. The stage-2 objective is a
plain regression onto the frozen teacher's ``z``: the target carries no gradient, so only the
adaptation module learns, whatever computed the target.
"""

from __future__ import annotations

from typing import Any

from unilab_jax import xp as shim


def adaptation_loss(z_pred: Any, z_target: Any) -> tuple[Any, dict[str, Any]]:
    """Mean squared error between the predicted and the teacher's latent, over every element.

    z_pred: [N, Z] adaptation-module output (differentiable); z_target: [N, Z] teacher latent
    (gradient stopped here). Returns ``(loss, metrics)``: the scalar loss and ``z_mse`` (the same
    value, gradient-stopped) and ``z_target_var`` (the variance of the target around its batch mean,
    summed over Z and divided by Z: the error a predictor of the batch mean would make, so the ratio
    of the two says how much of the latent the history explains).
    """
    xp = shim.namespace(z_pred, z_target)
    target = xp.stop_gradient(z_target)
    loss = xp.mean(xp.square(z_pred - target))
    centred = target - xp.mean(target, axis=0, keepdims=True)
    metrics = {"z_mse": xp.stop_gradient(loss), "z_target_var": xp.mean(xp.square(centred))}
    return loss, metrics
