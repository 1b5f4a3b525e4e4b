"""jax.jit-compiled kernels trace once for fixed shapes and agree with eager evaluation."""

from __future__ import annotations

import numpy as np
import pytest
from compile_options import FAST_COMPILE
from core_cases import CASE_IDS, CASES
from core_helpers import put

from unilab_jax import xp as shim

jax = pytest.importorskip("jax")
chex = pytest.importorskip("chex")


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_jitted_kernel_traces_once(case):
    chex.clear_trace_counter()
    jx = shim.get("jax")
    static = case.make(np.random.default_rng(0))[1]

    def kernel(*arrays):
        return case.fn(*arrays, **static)

    jitted = jax.jit(chex.assert_max_traces(kernel, n=1), compiler_options=FAST_COMPILE)
    for seed in (0, 1, 2):  # new values, same shapes: no retrace
        args = put(jx, case.make(np.random.default_rng(seed))[0])
        compiled, eager = jitted(*args), case.fn(*args, **static)
        # Same tree, shapes and dtypes as the eager kernel (jit must not promote or drop a leaf), same values.
        chex.assert_trees_all_equal_shapes_and_dtypes(compiled, eager)
        chex.assert_trees_all_close(compiled, eager, rtol=1e-5, atol=1e-6)


def test_hyperparameters_can_be_traced():
    # Loss coefficients and discounts passed as traced scalars do not force a retrace when they change.
    from unilab_jax.core.gae import gae
    from unilab_jax.core.ppo_losses import ppo_loss

    chex.clear_trace_counter()
    jx = shim.get("jax")
    rng = np.random.default_rng(0)

    @jax.jit
    @chex.assert_max_traces(n=1)
    def step(x, gamma, lam, clip_eps, vf_coef):
        adv, ret = gae(x, x, x, x > 1.0, x < -1.0, gamma, lam)
        flat = lambda a: jx.reshape(a, (-1,))
        return ppo_loss(flat(x), flat(x) * 0.9, flat(adv), flat(x), flat(x), flat(ret), flat(x),
                        clip_eps, 0.2, vf_coef, 0.01)

    for gamma, lam, clip_eps in ((0.99, 0.95, 0.2), (0.9, 0.5, 0.1)):
        x = jx.from_numpy(rng.normal(size=(8, 4)).astype(np.float32))
        out = step(x, gamma, lam, clip_eps, 1.0)
        assert np.isfinite(float(out[0]))


def test_retrace_guard_is_live():
    # Control: a new shape does retrace, and the guard notices (so the tests above are not vacuous).
    from unilab_jax.core.td3_losses import td3_actor_loss

    chex.clear_trace_counter()
    jitted = jax.jit(chex.assert_max_traces(td3_actor_loss, n=1))
    jitted(jax.numpy.ones(4))
    with pytest.raises(AssertionError, match="traced > 1 times"):
        jitted(jax.numpy.ones(5))
    chex.clear_trace_counter()
