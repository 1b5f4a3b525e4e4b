"""``compute_dtype``: bf16 matrix multiplies (float32 accumulation, results and master weights) in the JAX
off-policy learners; float32 stays the exact float32 program.

On CPU XLA has no bf16 x bf16 -> f32 dot, so the shim multiplies the bf16-rounded operands in float32: the
same products as the GPU's bf16 GEMMs (a product of two bf16 numbers is exact in float32), so these tests
check the numerics the GPU runs, up to summation order.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from compile_options import FAST_COMPILE

jax = pytest.importorskip("jax")
jnp = jax.numpy

from tasks.base import TaskSpec  # noqa: E402
from unilab_jax import algos, nets  # noqa: E402
from unilab_jax import xp as shim  # noqa: E402
from unilab_jax.algos.offpolicy import learner_common as common  # noqa: E402
from unilab_jax.algos.offpolicy import learner_jax as offpolicy_jax  # noqa: E402
from unilab_jax.algos.offpolicy.sac import Norms  # noqa: E402
from unilab_jax.core import normalizer  # noqa: E402

XP = shim.get("jax")
SPEC = TaskSpec("go1_sizes", 48, 123, 12, 1, 0.02, ())  # Go1's observation sizes
B = 256


def _batch(rng: np.random.Generator, u: int) -> dict:
    f = np.float32
    return {"obs": rng.normal(size=(u, B, 48)).astype(f), "critic_obs": rng.normal(size=(u, B, 123)).astype(f),
            "action": np.tanh(rng.normal(size=(u, B, 12))).astype(f), "reward": rng.random((u, B)).astype(f),
            "next_obs": rng.normal(size=(u, B, 48)).astype(f),
            "next_critic_obs": rng.normal(size=(u, B, 123)).astype(f),
            "terminated": rng.random((u, B)) < 0.05, "truncated": np.zeros((u, B), bool)}


def _config(name: str, dtype: str):
    return dataclasses.replace(algos.get(name).Config(), batch_size=B, updates_per_call=2, compute_dtype=dtype,
                               actor_hidden=(128, 64), critic_hidden=(256, 128))


def _learner(name: str, dtype: str):
    cfg = _config(name, dtype)
    if name == "td3":
        return offpolicy_jax.TD3Learner(cfg, SPEC, compiler_options=FAST_COMPILE)
    return offpolicy_jax.SACFamilyLearner(algos.get(name), cfg, SPEC, compiler_options=FAST_COMPILE)


def test_config_choices_auto_and_mlx():
    with pytest.raises(ValueError, match="compute_dtype"):
        algos.get("fastsac").Config(compute_dtype="float16")
    cfg = algos.get("fastsac").Config()
    assert cfg.compute_dtype == "auto"
    assert common.compute_dtype(cfg, "cpu") == "float32" and common.compute_dtype(cfg, "gpu") == "bfloat16"
    assert common.compute_dtype(cfg, "mlx") == "float32"
    with pytest.raises(ValueError, match="MLX learners compute in float32"):
        common.compute_dtype(dataclasses.replace(cfg, compute_dtype="bfloat16"), "mlx")
    assert _learner("sac", "auto").compute_dtype == "float32"  # this machine's jax backend is the CPU


def test_matmul_rounds_operands_and_keeps_float32_results_and_gradients():
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=(32, 24)), jnp.float32)
    w = jnp.asarray(rng.normal(size=(2, 24, 16)), jnp.float32)  # an ensemble: [E, in, out] broadcast against x

    def loss(w, x):
        return jnp.sum(jnp.tanh(XP.matmul(x, w)) ** 2)

    with XP.compute_dtype("bfloat16"):
        y = XP.matmul(x, w)
        gw, gx = jax.jit(jax.grad(loss, argnums=(0, 1)))(w, x)
    assert y.dtype == jnp.float32 and gw.dtype == gx.dtype == jnp.float32 and gx.shape == x.shape
    # Forward: exactly the float32 product of the bf16-rounded operands (bf16 products are exact in float32).
    r = lambda a: np.asarray(a.astype(jnp.bfloat16).astype(jnp.float32), np.float64)
    np.testing.assert_allclose(np.asarray(y), r(x) @ r(w), rtol=1e-5, atol=1e-5)
    # Gradients: within bf16 rounding (8 bits of mantissa) of float32's, in relative global norm.
    gw32, gx32 = jax.grad(loss, argnums=(0, 1))(w, x)
    for g, g32 in ((gw, gw32), (gx, gx32)):
        assert float(jnp.linalg.norm(g - g32) / jnp.linalg.norm(g32)) < 2e-2
    # Outside the block (and in "float32") the plain float32 matmul.
    with XP.compute_dtype("float32"):
        np.testing.assert_array_equal(np.asarray(XP.matmul(x, w)), np.asarray(jnp.matmul(x, w)))
    np.testing.assert_array_equal(np.asarray(XP.matmul(x, w)), np.asarray(jnp.matmul(x, w)))


@pytest.mark.parametrize("name", ["fastsac", "flashsac"])
def test_one_update_close_to_float32(name):
    """Same init and batch: the losses and gradient norms of one update (2 gradient steps) agree within 1%
    (measured: <= 0.06%), the loss gradients within 2% (measured ~0.3-0.6%); the bf16 program holds bf16
    converts, the float32 one none, and the parameters stay float32."""
    rng = np.random.default_rng(1)
    batch = _batch(rng, 2)
    states, metrics = {}, {}
    for dtype in ("float32", "bfloat16"):
        learner = _learner(name, dtype)
        text = learner._update_jit.lower(learner.init(jax.random.PRNGKey(0)), batch).as_text()
        assert ("bf16" in text) == (dtype == "bfloat16")
        states[dtype], m = learner.update(learner.init(jax.random.PRNGKey(0)), batch)
        metrics[dtype] = {k: float(v) for k, v in m.items()}
    assert all(leaf.dtype == jnp.float32 for leaf in jax.tree_util.tree_leaves((states["bfloat16"].actor,
                                                                                 states["bfloat16"].critic)))
    for k in ("critic_loss", "actor_loss", "critic_grad_norm", "actor_grad_norm", "q_mean", "entropy"):
        assert metrics["bfloat16"][k] == pytest.approx(metrics["float32"][k], rel=1e-2, abs=1e-4), k
    # The critic loss's gradient at the initial parameters, float32 vs bf16.
    mod, cfg = algos.get(name), _config(name, "float32")
    state = _learner(name, "float32").init(jax.random.PRNGKey(0))
    norms = Norms(normalizer.stats_init(48, XP), normalizer.stats_init(123, XP), jnp.ones((), jnp.float32))
    mb = {k: jnp.asarray(v[0], jnp.float32) for k, v in batch.items()}
    eps = jnp.asarray(rng.normal(size=(B, 12)), jnp.float32)

    def grad():
        # Jitted, the inputs passed as arguments (not closed over: XLA would constant-fold the products): one
        # compilation instead of hundreds of op-by-op ones (~20 s on the 2-core VM). A fresh function per call, so
        # each compute_dtype block traces its own program; the same bf16-vs-float32 difference as the eager calls
        # gave (measured, jitted / eager: FastSAC 2.1900e-3 / 2.1897e-3, FlashSAC 1.3665e-2 / 1.3664e-2).
        def flat(critic, target_critic, actor, log_alpha, norms, mb, eps):
            g, _ = jax.grad(mod.critic_loss, has_aux=True)(critic, target_critic, actor, log_alpha, norms, mb, eps, cfg)
            return jnp.concatenate([jnp.ravel(leaf) for leaf in jax.tree_util.tree_leaves(g)])

        return jax.jit(flat, compiler_options=FAST_COMPILE)(state.critic, state.target_critic, state.actor,
                                                            state.log_alpha, norms, mb, eps)

    g32 = grad()
    with XP.compute_dtype("bfloat16"):
        g16 = grad()
    assert 0.0 < float(jnp.linalg.norm(g16 - g32) / jnp.linalg.norm(g32)) < 2e-2  # > 0: the bf16 program ran


@pytest.mark.parametrize("name", ["fastsac", "td3"])
def test_bf16_learns_the_contextual_bandit(name):
    """reward = -||a - f(obs)||^2, every transition terminal (``test_offpolicy_learners``' bandit): bf16 finds
    f as float32 does. Measured action errors after training, seeds 5/6/7: FastSAC float32 0.0127/0.0141/0.0142,
    bf16 0.0127/0.0142/0.0141; TD3 float32 0.0135/0.0206/0.0156, bf16 0.0138/0.0214/0.0160. Threshold 0.1."""
    from test_offpolicy_learners import COMMON, OBS, SETUPS, _best_action
    from test_offpolicy_learners import _batch as bandit_batch

    mod = algos.get(name)
    cfg = dataclasses.replace(mod.Config(), **{**COMMON, **SETUPS[name][0]}, compute_dtype="bfloat16")
    spec = TaskSpec("bandit", OBS, OBS, 2, 1, 0.02, ())
    learner = (offpolicy_jax.TD3Learner(cfg, spec, compiler_options=FAST_COMPILE) if name == "td3" else
               offpolicy_jax.SACFamilyLearner(mod, cfg, spec, compiler_options=FAST_COMPILE))
    rng = np.random.default_rng(5)
    test_obs = rng.normal(size=(512, OBS)).astype(np.float32)

    def error(state) -> float:
        action, _ = mod.act(nets.to_numpy(learner.weights(state)), test_obs, np.zeros((512, 2), np.float32), True)
        return float(np.mean(np.sum((action - _best_action(test_obs)) ** 2, -1)))

    state = learner.init(jax.random.PRNGKey(5))
    start = error(state)
    for _ in range(SETUPS[name][1]):
        state, _ = learner.update(state, bandit_batch(rng, cfg.updates_per_call))
    assert start > 0.5 and error(state) < 0.1, f"{name} bf16: action error {start:.3f} -> {error(state):.3f}"
