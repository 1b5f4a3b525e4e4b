"""``compute_dtype``: bf16 matrix multiplies (float32 accumulation, results and master weights) in the JAX
off-policy learners; float32 stays the exact float32 program.

On CPU XLA has no bf16 x bf16 -> f32 dot, so the shim multiplies the bf16-rounded operands in float32: the
same products as the GPU's bf16 GEMMs (a product of two bf16 numbers is exact in float32), so these tests
check the numerics the GPU runs, up to summation order.
"""

from __future__ import annotations

import dataclasses
import re

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


def _config(name: str, dtype: str, ln: str = "xla"):
    """``ln``: the LayerNorm kernels, "xla", "pallas" (forward and backward) or "pallas_backward"."""
    kernels = {"xla": ("xla", "xla"), "pallas": ("pallas", "pallas"), "pallas_backward": ("xla", "pallas")}
    forward, backward = kernels[ln]
    return dataclasses.replace(algos.get(name).Config(), batch_size=B, updates_per_call=2, compute_dtype=dtype,
                               actor_hidden=(128, 64), critic_hidden=(256, 128), ln_forward=forward,
                               ln_backward=backward)


def _learner(name: str, dtype: str, ln: str = "xla"):
    cfg = _config(name, dtype, ln)
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


def test_layer_norm_relu_kernel_matches_float64_reference():
    """``mixed_precision.layer_norm_relu``'s hand-written backward against autodiff of the plain float32 function
    of the same bf16 input: values within one bf16 rounding of a float64 reference, parameter gradients within
    1e-4 relative, the input's within bf16 rounding (the kernel returns it in bf16)."""
    from unilab_jax import mixed_precision as mp

    rng = np.random.default_rng(3)
    h = jnp.asarray(rng.normal(size=(2, 64, 96)) * 3 + 1, jnp.bfloat16)  # an ensemble's [E, B, W] matmul output
    b, g, o = (jnp.asarray(rng.normal(size=(2, 1, 96)) * s + m, jnp.float32) for s, m in ((1, 0), (0.3, 1), (0.5, 0)))
    dy = jnp.asarray(rng.normal(size=(2, 64, 96)), jnp.bfloat16)
    y, vjp = jax.vjp(mp.layer_norm_relu, h, b, g, o)
    grads = vjp(dy)
    assert y.dtype == jnp.bfloat16 and grads[0].dtype == jnp.bfloat16 and grads[1].dtype == jnp.float32

    def reference(h, b, g, o):
        x = h + b
        xhat = (x - x.mean(-1, keepdims=True)) / np.sqrt(x.var(-1, keepdims=True) + mp.EPS)
        return np.maximum(xhat * g + o, 0.0)

    f64 = [np.asarray(a, np.float64) for a in (h.astype(jnp.float32), b, g, o)]
    np.testing.assert_allclose(np.asarray(y, np.float64), reference(*f64), rtol=8e-3, atol=8e-3)
    _, ref_vjp = jax.vjp(lambda *a: jnp.maximum(_plain_ln(*a, mp.EPS), 0.0), h.astype(jnp.float32), b, g, o)
    ref = ref_vjp(dy.astype(jnp.float32))
    for got, want, tol in zip(grads, ref, (8e-3, 1e-4, 1e-4, 1e-4), strict=True):
        err = np.linalg.norm(np.asarray(got, np.float64) - np.asarray(want)) / np.linalg.norm(np.asarray(want))
        assert err < tol, (err, tol)


def _ln_case(rng, h_shape, p_shape):
    from unilab_jax import mixed_precision as mp

    h = jnp.asarray(rng.normal(size=h_shape) * 3 + 1, jnp.bfloat16)
    b, g, o = (jnp.asarray(rng.normal(size=p_shape) * s + m, jnp.float32) for s, m in ((1, 0), (0.3, 1), (0.5, 0)))
    return mp._ln_fwd(h, b, g, o)[1], jnp.asarray(rng.normal(size=h_shape), jnp.bfloat16)


@pytest.mark.parametrize("h_shape, p_shape", [((2, 64, 128), (2, 1, 128)), ((2, 100, 32), (32,)), ((100, 64), (64,)),
                                              ((3, 40, 16), (3, 40, 16))])
def test_pallas_ln_backward_matches_xla(h_shape, p_shape):
    """The fused Pallas backward (interpreted on the CPU) against ``_ln_bwd``: an ensemble [E, B, W] with per-member
    parameters, B = 100 (not a multiple of the 64-row block: padded rows) with [W] parameters, a 2-D [B, W]; the
    parameter gradients within 1e-5 relative, dh (bf16) within one bf16 step. Parameters that vary along the
    rows (the last case) are not the kernel's: that one takes the XLA backward (no Pallas call) and is exact."""
    from unilab_jax import mixed_precision as mp

    res, dy = _ln_case(np.random.default_rng(5), h_shape, p_shape)
    fused = jax.jit(mp._ln_bwd_pallas)
    assert ("pallas_call" in str(jax.make_jaxpr(fused)(res, dy))) == (p_shape[-2:-1] != (40,))
    got, want = fused(res, dy), mp._ln_bwd(res, dy)
    for a, w, tol in zip(got, want, (None, 1e-5, 1e-5, 1e-5), strict=True):
        assert a.shape == w.shape and a.dtype == w.dtype
        a, w = np.asarray(a, np.float64), np.asarray(w, np.float64)
        if tol is None:  # both round a float32 dh to bf16 (8 significant bits); summed in another order, the two
            # float32 values can fall either side of a rounding boundary: one bf16 step apart, at most 2^-7 of the value
            # (the GPU's Triton kernel: 2 of 6,400 elements of the [100, 64] case, 0.76% apart)
            assert np.all(np.abs(a - w) <= 2.0 ** -7 * np.abs(w) + 1e-6)
        else:
            assert np.linalg.norm(a - w) <= tol * np.linalg.norm(w)
    assert float(np.abs(np.asarray(got[1])).max()) > 0.1  # the sums are not all zero


@pytest.mark.parametrize("h_shape, p_shape", [((2, 64, 128), (2, 1, 128)), ((2, 100, 32), (32,)), ((100, 64), (64,)),
                                              ((3, 40, 16), (3, 40, 16))])
def test_pallas_ln_forward_matches_xla(h_shape, p_shape):
    """The fused Pallas forward (interpreted on the CPU) against ``_ln_fwd``'s XLA program, the same cases as the
    backward's: the output (bf16) within one bf16 step (both round the same float32 value, summed in another
    order), the saved mean and 1/std within 1e-6 relative; parameters varying along the rows take XLA's program."""
    from unilab_jax import mixed_precision as mp

    (h, b, g, o, mu, rstd), _ = _ln_case(np.random.default_rng(7), h_shape, p_shape)
    fused = jax.jit(lambda *a: mp._ln_fwd(*a, forward="pallas"))
    assert ("pallas_call" in str(jax.make_jaxpr(fused)(h, b, g, o))) == (p_shape[-2:-1] != (40,))
    y, (_, _, _, _, mu_p, rstd_p) = fused(h, b, g, o)
    y_xla = mp._ln_fwd(h, b, g, o)[0]
    assert y.shape == y_xla.shape and y.dtype == y_xla.dtype == jnp.bfloat16
    a, w = np.asarray(y, np.float64), np.asarray(y_xla, np.float64)
    assert np.all(np.abs(a - w) <= 2.0 ** -7 * np.abs(w) + 1e-6) and np.mean(a > 0) > 0.2
    for got, want in ((mu_p, mu), (rstd_p, rstd)):
        assert got.shape == want.shape
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-6, atol=1e-6)


def test_pallas_ln_forward_lowers_to_triton_for_a_gpu():
    """Lowered for CUDA at FastSAC Go1's first critic layer ([2, 8192, 1024]): one Triton call, no float32 copy of
    ``h`` (its rows' statistics come back as [2, 8192, 1])."""
    import functools

    from unilab_jax import mixed_precision as mp
    from unilab_jax import pallas_kernels

    args = [jax.ShapeDtypeStruct((2, 8192, 1024), jnp.bfloat16)] + [jax.ShapeDtypeStruct((2, 1, 1024), jnp.float32)] * 3
    fused = jax.jit(functools.partial(pallas_kernels.ln_relu_forward, eps=mp.EPS, interpret=False))
    text = fused.trace(*args).lower(lowering_platforms=("cuda",)).as_text()
    assert text.count("xla.gpu.triton") == 1 and "tensor<2x8192x1024xf32>" not in text


def test_pallas_ln_backward_lowers_to_triton_for_a_gpu():
    """Lowered for CUDA from this CPU machine at FastSAC Go1's first critic layer ([2, 8192, 1024]): one Triton call
    (jax's default GPU lowering, Mosaic GPU, would stage the 64-row blocks in shared memory and refuse them)."""
    import functools

    from unilab_jax import pallas_kernels

    f32, bf16 = jnp.float32, jnp.bfloat16
    shapes = [((2, 8192, 1024), bf16)] * 2 + [((2, 8192, 1), f32)] * 2 + [((2, 1, 1024), f32)] * 3
    args = [jax.ShapeDtypeStruct(shape, dtype) for shape, dtype in shapes]
    fused = jax.jit(functools.partial(pallas_kernels.ln_relu_backward, interpret=False))
    text = fused.trace(*args).lower(lowering_platforms=("cuda",)).as_text()
    assert text.count("xla.gpu.triton") == 1 and "tensor<2x128x1024xf32>" in text  # 128 blocks of 64 rows


@pytest.mark.parametrize("forward, backward", [("xla", "pallas"), ("pallas", "xla"), ("pallas", "pallas")])
def test_ln_kernels_switch_picks_the_kernels_at_trace_time(forward, backward):
    """``mp.ln_kernels(forward, backward)`` makes ``layer_norm_relu`` (its value and its vjp) trace the Pallas
    kernels it names, only inside the block (one ``pallas_call`` per "pallas" pass); they give XLA's values and
    gradients; an unknown name is refused, in the context and in the learners' config."""
    from unilab_jax import mixed_precision as mp

    (h, b, g, o, _, _), dy = _ln_case(np.random.default_rng(6), (2, 64, 32), (2, 1, 32))
    def value_and_grads():  # a fresh function per block: jax caches a function's traces without the thread's setting
        def f(h, b, g, o, dy):
            y, vjp = jax.vjp(mp.layer_norm_relu, h, b, g, o)
            return y, vjp(dy)
        return jax.jit(f)

    with mp.ln_kernels(forward, backward):
        fused = value_and_grads()
        assert str(jax.make_jaxpr(fused)(h, b, g, o, dy)).count("pallas_call") == [forward, backward].count("pallas")
        got = fused(h, b, g, o, dy)
    xla = value_and_grads()
    assert "pallas_call" not in str(jax.make_jaxpr(xla)(h, b, g, o, dy))
    (y, grads), (y_xla, grads_xla) = got, xla(h, b, g, o, dy)
    for a, w, rtol in zip((y, *grads), (y_xla, *grads_xla), (2.0 ** -7, 2.0 ** -7, 1e-5, 1e-5, 1e-5), strict=True):
        np.testing.assert_allclose(np.asarray(a, np.float32), np.asarray(w, np.float32), rtol=rtol, atol=1e-5)
    for what in ("ln_forward", "ln_backward"):
        with pytest.raises(ValueError, match=what), mp.ln_kernels(**{what[3:]: "triton"}):
            pass
        with pytest.raises(ValueError, match=what):
            algos.get("fastsac").Config(**{what: "triton"})


@pytest.mark.parametrize("ln", ["pallas_backward", "pallas"])
def test_fastsac_update_with_pallas_ln_kernels_matches_xla(ln):
    """One bf16 FastSAC update (2 gradient steps, LayerNorm critics) with the Pallas backward alone and with both
    Pallas passes traces the kernels and lands where "xla" does: the critic's parameter update within 3% of XLA's
    (relative norm; measured 7.4e-5 with the Pallas backward, with both passes 1.25e-3 here and 1.1e-2 on an H100,
    where XLA's program takes the LayerNorm statistics from a float32 matmul result and the Pallas forward from the
    bf16 one; the float32 program's update is 8.8% from bf16's here); the metrics within 1e-4 relative with the
    Pallas backward, within bf16 rounding (1e-2, as against float32) with both (H100: actor loss 1.5e-3 apart)."""
    rng = np.random.default_rng(2)
    batch = _batch(rng, 2)
    out = {}
    for kernels in ("xla", ln):
        learner = _learner("fastsac", "bfloat16", kernels)
        state = learner.init(jax.random.PRNGKey(0))
        assert ("pallas_call" in str(jax.make_jaxpr(learner.traced_update)(state, batch))) == (kernels != "xla")
        out[kernels] = learner.update(state, batch)  # donates ``state`` on accelerators
    (s_xla, m_xla), (s_pl, m_pl) = out["xla"], out[ln]
    rel = 1e-4 if ln == "pallas_backward" else 1e-2
    for k in ("critic_loss", "actor_loss", "critic_grad_norm", "actor_grad_norm", "q_mean"):
        assert float(m_pl[k]) == pytest.approx(float(m_xla[k]), rel=rel, abs=1e-6), k
    flat = lambda c: jnp.concatenate([jnp.ravel(a) for a in jax.tree_util.tree_leaves(c)])
    start = flat(learner.init(jax.random.PRNGKey(0)).critic)
    step_xla, step_pl = flat(s_xla.critic) - start, flat(s_pl.critic) - start
    assert float(jnp.linalg.norm(step_pl - step_xla)) < 3e-2 * float(jnp.linalg.norm(step_xla))


def _plain_ln(h, b, g, o, eps):
    x = h + b
    mu = x.mean(-1, keepdims=True)
    return (x - mu) / jnp.sqrt(((x - mu) ** 2).mean(-1, keepdims=True) + eps) * g + o


def test_layer_norm_critic_keeps_bf16_activations_between_matmuls():
    """Under bf16 a LayerNorm + ReLU critic's hidden activations are bf16 (forward and in the backward pass),
    its output and parameter gradients float32, and the whole critic's gradient stays within bf16 rounding of
    the float32 program's."""
    rng = np.random.default_rng(4)
    params = nets.init(jax.random.PRNGKey(0), (32, 64, 48, 1), XP, layer_norm=True)
    x = jnp.asarray(rng.normal(size=(128, 32)), jnp.float32)

    def loss(params, x):
        return jnp.mean(nets.apply(params, x, "relu") ** 2)

    with XP.compute_dtype("bfloat16"):
        hidden = XP.dense(x, params[0]["w"], params[0]["b"], params[0]["g"], params[0]["o"], "relu")
        out = nets.apply(params, x, "relu")
        jaxpr = str(jax.make_jaxpr(jax.grad(loss))(params, x))
        g16 = jax.grad(loss)(params, x)
    assert hidden.dtype == jnp.bfloat16 and out.dtype == jnp.float32
    assert "bf16[128,64]" in jaxpr and "bf16[128,48]" in jaxpr
    assert all(leaf.dtype == jnp.float32 for leaf in jax.tree_util.tree_leaves(g16))
    g32 = jax.grad(loss)(params, x)
    flat = lambda t: jnp.concatenate([jnp.ravel(a) for a in jax.tree_util.tree_leaves(t)])
    assert 0.0 < float(jnp.linalg.norm(flat(g16) - flat(g32)) / jnp.linalg.norm(flat(g32))) < 2e-2


def _conv_types(hlo: str) -> list[tuple[str, str, str]]:
    """(lhs, rhs, result) element types of every ``stablehlo.convolution`` in a lowered program."""
    sig = re.compile(r"stablehlo\.convolution.*: \(tensor<[^>]*x(\w+)>, tensor<[^>]*x(\w+)>\) -> tensor<[^>]*x(\w+)>")
    return [m.groups() for m in map(sig.search, hlo.splitlines()) if m]


def test_encoder_convolutions_lower_to_bf16_forward_and_backward():
    """The image encoder's parameter gradient under bf16: every convolution of the lowered program, the forward
    ones and both backward ones (input and weight gradients), takes bf16 operands and writes bf16 (XLA's GPU
    compiler would turn a bf16 x bf16 -> float32 convolution back into a float32 one); under float32 all are
    float32. Two layers: 2 forward, 2 weight-gradient and 1 input-gradient convolutions (the image gets none)."""
    from unilab_jax.core import pixels

    params = pixels.encoder_init(jax.random.PRNGKey(0), (16, 16, 12), (8, 8), (2, 1), 10, XP)
    image = jnp.asarray(np.random.default_rng(0).integers(0, 256, (4, 16, 16, 12)), jnp.uint8)

    def loss(params, image):
        return jnp.sum(pixels.encode(params, image, (2, 1)) ** 2)

    with XP.compute_dtype("bfloat16"):
        text16 = jax.jit(jax.grad(loss)).lower(params, image).as_text()
    text32 = jax.jit(jax.grad(loss)).lower(params, image).as_text()
    assert _conv_types(text16) == [("bf16", "bf16", "bf16")] * 5
    assert _conv_types(text32) == [("f32", "f32", "f32")] * 5


@pytest.mark.parametrize("stride", [1, 2])
def test_conv2d_within_bf16_rounding_of_float32(stride):
    """``conv2d`` under bf16 against the float32 convolution, values and both gradients, elementwise: each is a
    sum of products of two bf16-rounded factors (relative error <= 2u + u^2 each, u = 2^-8 bf16's unit roundoff),
    accumulated in float32 and rounded to bf16 once (<= u), so |bf16 - float32| <= (3u + 4u^2 + K 2^-23) S, with
    S the same sum over absolute values and K its number of terms. Results and gradients are float32; outside the
    block the plain float32 convolution."""
    rng = np.random.default_rng(2)
    n = (9 - 3) // stride + 1  # output pixels per side
    x, w, g = (jnp.asarray(rng.normal(size=s), jnp.float32) for s in ((4, 9, 9, 12), (3, 3, 12, 8), (4, n, n, 8)))
    conv32 = lambda a, b: jax.lax.conv_general_dilated(a, b, (stride, stride), "VALID",
                                                       dimension_numbers=("NHWC", "HWIO", "NHWC"))
    with XP.compute_dtype("bfloat16"):
        y16, vjp16 = jax.vjp(lambda a, b: XP.conv2d(a, b, stride), x, w)
    dx16, dw16 = vjp16(g)
    y32, vjp32 = jax.vjp(conv32, x, w)
    bounds_of = jax.vjp(conv32, jnp.abs(x), jnp.abs(w))
    terms = (9 * 12, 8 * 9, int(np.prod(g.shape[:3])))  # K of y, dx (at most: Cout x window), dw
    u = 2.0 ** -8
    for got, want, s, k in zip((y16, dx16, dw16), (y32, *vjp32(g)), (bounds_of[0], *bounds_of[1](jnp.abs(g))), terms,
                               strict=True):
        assert got.dtype == jnp.float32
        err = np.abs(np.asarray(got, np.float64) - np.asarray(want, np.float64))
        assert np.all(err <= (3 * u + 4 * u * u + k * 2.0 ** -23) * np.asarray(s, np.float64) + 1e-30)
        assert err.max() > 0  # the bf16 program ran
    np.testing.assert_array_equal(np.asarray(XP.conv2d(x, w, stride)), np.asarray(conv32(x, w)))


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



class _Device:
    """What ``learner_common.resolve_ln_kernels`` reads of a jax device."""

    def __init__(self, platform: str, version: str, capability: str | None, kind: str = ""):
        self.platform, self.compute_capability, self.device_kind = platform, capability, kind
        self.client = type("Client", (), {"platform_version": version})()


@pytest.mark.parametrize(("devices", "dtype", "want"), [
    ([_Device("gpu", "cuda 12080", "9.0")], "bfloat16", "pallas"),     # one H100
    ([_Device("gpu", "cuda 12080", "8.6")], "bfloat16", "pallas"),     # one Ampere card
    ([_Device("gpu", "cuda 12080", "7.5")], "bfloat16", "xla"),        # Turing: no bf16 in Triton
    ([_Device("gpu", "cuda 12080", "9.0")] * 2, "bfloat16", "xla"),    # a Pallas call is one device's program
    ([_Device("gpu", "cuda 12080", "9.0")], "float32", "xla"),         # the float32 program has no bf16 layers
    ([_Device("gpu", "rocm 60342", "gfx942", "AMD Instinct MI300X")], "bfloat16", "xla"),  # ROCm
    ([_Device("gpu", "<unknown>", "9.0", "NVIDIA H100 80GB HBM3")], "bfloat16", "pallas"),  # named by its kind only
    ([_Device("cpu", "cpu", None)], "bfloat16", "xla"),
])
def test_auto_ln_kernels_are_pallas_on_one_nvidia_gpu_only(devices, dtype, want):
    auto = algos.get("fastsac").Config()
    assert (auto.ln_forward, auto.ln_backward) == ("auto", "auto")
    assert common.resolve_ln_kernels(auto, dtype, devices) == (want, want)
    chosen = dataclasses.replace(auto, ln_forward="xla", ln_backward="pallas")
    assert common.resolve_ln_kernels(chosen, dtype, devices) == ("xla", "pallas")  # a name other than "auto" is kept


def test_learner_on_this_cpu_resolves_auto_to_xla():
    cfg = dataclasses.replace(_config("fastsac", "bfloat16"), ln_forward="auto", ln_backward="auto")
    learner = offpolicy_jax.SACFamilyLearner(algos.get("fastsac"), cfg, SPEC, compiler_options=FAST_COMPILE)
    assert learner.ln_kernels == ("xla", "xla")
    state, batch = learner.init(jax.random.PRNGKey(0)), _batch(np.random.default_rng(0), 2)
    assert "pallas_call" not in str(jax.make_jaxpr(learner.traced_update)(state, batch))


@pytest.mark.skipif(jax.default_backend() != "gpu", reason="reads a real GPU (bench/p31_ln.sh runs it on the H100)")
def test_auto_ln_kernels_pick_pallas_on_this_nvidia_gpu():
    """What the fake devices above stand for: this jax's CUDA device names its platform and compute capability."""
    device = jax.devices()[0]
    assert "cuda" in device.client.platform_version.lower() and "nvidia" in device.device_kind.lower()
    assert int(device.compute_capability.split(".")[0]) >= 8
    assert common.resolve_ln_kernels(algos.get("fastsac").Config(), "bfloat16", [device]) == ("pallas", "pallas")
