"""unilab_mlx.optim against optax: same params, same gradient sequences, same results (float32).

Each case runs STEPS updates on MLX and on optax (jax CPU, the reference) and compares the
parameters after every step.
"""

from __future__ import annotations

import numpy as np
import pytest

mx = pytest.importorskip("mlx.core")
jax = pytest.importorskip("jax")
optax = pytest.importorskip("optax")
import jax.numpy as jnp  # noqa: E402

from unilab_jax.xp import tree_leaves, tree_map  # noqa: E402
from unilab_mlx import optim  # noqa: E402

STEPS = 20
RTOL = 1e-5
ATOL = 1e-7


# ---------------------------------------------------------------------------------------------
# harness
# ---------------------------------------------------------------------------------------------
def _params(seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    f = lambda *s: rng.normal(size=s).astype(np.float32)
    return {"layers": [{"w": f(4, 8), "b": f(8)}, {"w": f(8, 3), "b": f(3)}], "log_std": f(3)}


def _grads(seed: int = 1, scales: tuple[float, ...] = (1.0,)) -> list[dict]:
    """STEPS gradient pytrees; step i is scaled by scales[i % len(scales)]."""
    rng = np.random.default_rng(seed)
    p = _params()
    out = []
    for i in range(STEPS):
        s = scales[i % len(scales)]
        out.append(tree_map(lambda x, s=s: (s * rng.normal(size=x.shape)).astype(np.float32), p))
    return out


def _np(tree):
    return tree_map(lambda x: np.array(x), tree)


def _run_mlx(opt, params, grads, edit=None):
    p = tree_map(mx.array, params)
    state = opt.init(p)
    out = []
    for i, g in enumerate(grads):
        if edit is not None:
            state = edit(i, state)
        updates, state = opt.update(tree_map(mx.array, g), state, p)
        p = optim.apply_updates(p, updates)
        mx.eval(p, state)
        out.append(_np(p))
    return out, state


def _run_optax(opt, params, grads, edit=None):
    p = tree_map(jnp.asarray, params)
    state = opt.init(p)
    out = []
    for i, g in enumerate(grads):
        if edit is not None:
            state = edit(i, state)
        updates, state = opt.update(tree_map(jnp.asarray, g), state, p)
        p = optax.apply_updates(p, updates)
        out.append(_np(p))
    return out, state


def _assert_same(got_seq, want_seq, rtol=RTOL, atol=ATOL):
    assert len(got_seq) == len(want_seq)
    for step, (got, want) in enumerate(zip(got_seq, want_seq)):
        for a, b in zip(tree_leaves(got), tree_leaves(want), strict=True):
            np.testing.assert_allclose(a, b, rtol=rtol, atol=atol, err_msg=f"step {step}")


def _moved(seq, params):
    """The optimizer actually changed every leaf (guards against comparing two no-ops)."""
    for a, b in zip(tree_leaves(seq[-1]), tree_leaves(params)):
        assert np.max(np.abs(a - b)) > 1e-4


def _compare(mlx_opt, optax_opt, grads=None, edit_mlx=None, edit_optax=None):
    params = _params()
    grads = _grads() if grads is None else grads
    got, mstate = _run_mlx(mlx_opt, params, grads, edit_mlx)
    want, ostate = _run_optax(optax_opt, params, grads, edit_optax)
    _assert_same(got, want)
    _moved(got, params)
    return mstate, ostate


def _decay_mask(params):
    """Decay weight matrices only (not biases, not log_std)."""
    return {"layers": [{"w": True, "b": False} for _ in params["layers"]], "log_std": False}


# ---------------------------------------------------------------------------------------------
# optimizers and transforms
# ---------------------------------------------------------------------------------------------
PREFIX_MASK = {"layers": True, "log_std": False}  # a mask that is a prefix of the params tree

CASES = {
    "sgd": (lambda m: m.sgd(0.05),),
    "sgd_momentum": (lambda m: m.sgd(0.02, momentum=0.9),),
    "sgd_nesterov": (lambda m: m.sgd(0.02, momentum=0.9, nesterov=True),),
    "scale_by_adam": (lambda m: m.chain(m.scale_by_adam(), m.scale(-0.01)),),
    "adam": (lambda m: m.adam(1e-2),),
    "adam_hparams": (lambda m: m.adam(3e-2, b1=0.8, b2=0.99, eps=1e-6, eps_root=1e-8),),
    "adam_nesterov": (lambda m: m.adam(1e-2, nesterov=True),),
    "adamw": (lambda m: m.adamw(1e-2, weight_decay=0.1),),
    "adamw_mask_tree": (lambda m: m.adamw(1e-2, weight_decay=0.5, mask=_decay_mask(_params())),),
    "adamw_mask_callable": (lambda m: m.adamw(1e-2, weight_decay=0.5, mask=_decay_mask),),
    "adamw_mask_prefix": (lambda m: m.adamw(1e-2, weight_decay=0.5, mask=PREFIX_MASK),),
    "masked_adam": (lambda m: m.chain(m.masked(m.scale_by_adam(), _decay_mask(_params())), m.scale(-0.01)),),
    "chain_clip_adam": (lambda m: m.chain(m.clip_by_global_norm(1.0), m.adam(1e-2)),),
    "decay_schedule": (
        lambda m: m.chain(m.add_decayed_weights(m.linear_schedule(0.5, 0.0, 15)), m.sgd(0.05)),),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_matches_optax(name):
    (make,) = CASES[name]
    mstate, ostate = _compare(make(optim), make(optax))
    # the same number of state arrays, holding the same values (dict keys happen to sort like optax fields
    # for these states; compare multiset of shapes to stay independent of ordering)
    m_shapes = sorted(tuple(np.shape(x)) for x in tree_leaves(mstate))
    o_shapes = sorted(tuple(np.shape(x)) for x in jax.tree.leaves(ostate))
    assert m_shapes == o_shapes


def test_clip_by_global_norm_clips():
    """Alternating tiny / large gradients: the large ones are rescaled to norm 1, the tiny pass through."""
    grads = _grads(scales=(0.01, 3.0))
    norms = [float(np.sqrt(sum(np.sum(x**2) for x in tree_leaves(g)))) for g in grads]
    assert min(norms) < 1.0 < max(norms)
    clip = optim.clip_by_global_norm(1.0)
    for g, n in zip(grads[:2], norms[:2]):
        u, _ = clip.update(tree_map(mx.array, g), clip.init(None))
        assert float(optim.global_norm(u)) == pytest.approx(min(n, 1.0), rel=1e-5)
    # applied directly (updates = clipped grads) and after adam
    _compare(optim.clip_by_global_norm(1.0), optax.clip_by_global_norm(1.0), grads=grads)
    _compare(optim.chain(optim.clip_by_global_norm(1.0), optim.adam(1e-2)),
             optax.chain(optax.clip_by_global_norm(1.0), optax.adam(1e-2)), grads=grads)


# ---------------------------------------------------------------------------------------------
# schedules
# ---------------------------------------------------------------------------------------------
SCHEDULES = {
    "constant": lambda m: m.constant_schedule(1e-2),
    "linear": lambda m: m.linear_schedule(1e-2, 1e-3, 10, transition_begin=5),
    "polynomial": lambda m: m.polynomial_schedule(1e-2, 1e-4, 2, 12, transition_begin=3),
    "cosine": lambda m: m.cosine_decay_schedule(1e-2, 15, alpha=0.1),
    "cosine_exponent": lambda m: m.cosine_decay_schedule(1e-2, 12, exponent=2.0),
    "warmup_cosine": lambda m: m.warmup_cosine_decay_schedule(0.0, 1e-2, 5, 15, end_value=1e-3),
}


@pytest.mark.parametrize("name", sorted(SCHEDULES))
def test_schedule_values(name):
    ms, os_ = SCHEDULES[name](optim), SCHEDULES[name](optax)
    for c in range(30):
        want = float(os_(jnp.asarray(c, jnp.int32)))
        assert float(ms(mx.array(c, dtype=mx.int32))) == pytest.approx(want, rel=1e-6, abs=1e-12)
        assert float(ms(c)) == pytest.approx(want, rel=1e-6, abs=1e-12)


@pytest.mark.parametrize("name", sorted(SCHEDULES))
def test_schedule_as_learning_rate(name):
    _compare(optim.adam(SCHEDULES[name](optim)), optax.adam(SCHEDULES[name](optax)))


# ---------------------------------------------------------------------------------------------
# injected hyperparameters
# ---------------------------------------------------------------------------------------------
def test_inject_lr_changed_mid_run():
    def edit_mlx(i, s):
        if i == 10:
            s["hyperparams"]["learning_rate"] = mx.array(3e-3)
        if i == 15:
            s = optim.set_hyperparams(s, learning_rate=2e-2, b2=0.9)
        return s

    def edit_optax(i, s):
        if i == 10:
            s.hyperparams["learning_rate"] = jnp.asarray(3e-3)
        if i == 15:
            s.hyperparams["learning_rate"] = jnp.asarray(2e-2, jnp.float32)
            s.hyperparams["b2"] = jnp.asarray(0.9, jnp.float32)
        return s

    mstate, ostate = _compare(optim.inject_hyperparams(optim.adam)(learning_rate=1e-2),
                              optax.inject_hyperparams(optax.adam)(learning_rate=1e-2),
                              edit_mlx=edit_mlx, edit_optax=edit_optax)
    assert sorted(mstate["hyperparams"]) == sorted(ostate.hyperparams)
    for k, v in mstate["hyperparams"].items():
        assert v.dtype == mx.float32 and float(v) == pytest.approx(float(ostate.hyperparams[k]), rel=1e-7)
    assert int(mstate["count"]) == int(ostate.count) == STEPS
    assert optim.get_hyperparams(mstate)["learning_rate"].item() == pytest.approx(2e-2)


def _kl_rule(xp, lr, kl, target=0.01):
    """rsl_rl's KL-adaptive learning rate, written with array ops on the state's lr."""
    lr = xp.where(kl > 2.0 * target, xp.maximum(lr / 1.5, 1e-5), lr)
    return xp.where(kl < 0.5 * target, xp.minimum(lr * 1.5, 1e-2), lr)


KLS = np.random.default_rng(7).uniform(0.0, 0.03, size=STEPS).astype(np.float32)


def test_inject_kl_adaptive_lr_in_chain():
    """chain(clip, inject(adam)): the lr follows a KL rule every step, read from and written to the state."""

    def edit_mlx(i, s):
        lr = _kl_rule(mx, s[1]["hyperparams"]["learning_rate"], mx.array(KLS[i]))
        return optim.set_hyperparams(s, learning_rate=lr)

    def edit_optax(i, s):
        hp = s[1].hyperparams
        hp["learning_rate"] = _kl_rule(jnp, hp["learning_rate"], jnp.asarray(KLS[i]))
        return s

    grads = _grads(scales=(0.3, 3.0))
    mstate, ostate = _compare(
        optim.chain(optim.clip_by_global_norm(1.0), optim.inject_hyperparams(optim.adam)(learning_rate=1e-3)),
        optax.chain(optax.clip_by_global_norm(1.0), optax.inject_hyperparams(optax.adam)(learning_rate=1e-3)),
        grads=grads, edit_mlx=edit_mlx, edit_optax=edit_optax)
    lr_m = float(mstate[1]["hyperparams"]["learning_rate"])
    lr_o = float(ostate[1].hyperparams["learning_rate"])
    assert lr_m == pytest.approx(lr_o, rel=1e-6) and lr_m != pytest.approx(1e-3)


def test_inject_schedule_and_static_mask():
    """A scheduled lr (tracked in hyperparams) and a callable mask passed as a static argument."""
    mstate, ostate = _compare(
        optim.inject_hyperparams(optim.adamw, static_args="mask")(
            learning_rate=optim.warmup_cosine_decay_schedule(0.0, 2e-2, 4, 16), weight_decay=0.3,
            mask=_decay_mask),
        optax.inject_hyperparams(optax.adamw, static_args="mask")(
            learning_rate=optax.warmup_cosine_decay_schedule(0.0, 2e-2, 4, 16), weight_decay=0.3,
            mask=_decay_mask))
    for k in ("learning_rate", "weight_decay", "b1"):
        assert float(mstate["hyperparams"][k]) == pytest.approx(float(ostate.hyperparams[k]), rel=1e-6)


def test_set_hyperparams_unknown_name():
    opt = optim.inject_hyperparams(optim.adam)(learning_rate=1e-3)
    state = opt.init(tree_map(mx.array, _params()))
    with pytest.raises(KeyError):
        optim.set_hyperparams(state, momentum=0.5)
    with pytest.raises(KeyError):
        optim.set_hyperparams(optim.adam(1e-3).init(tree_map(mx.array, _params())), learning_rate=0.5)


# ---------------------------------------------------------------------------------------------
# mx.compile with the state as explicit inputs/outputs
# ---------------------------------------------------------------------------------------------
def _make_opt():
    return optim.chain(
        optim.clip_by_global_norm(1.0),
        optim.inject_hyperparams(optim.adamw, static_args="mask")(
            learning_rate=1e-3, weight_decay=0.1, mask=_decay_mask))


def _compiled_run(compiled: bool):
    opt = _make_opt()
    params = tree_map(mx.array, _params())
    state = {"params": params, "opt": opt.init(params)}
    traces = []

    def step(grads, kl):
        traces.append(1)
        lr = _kl_rule(mx, state["opt"][1]["hyperparams"]["learning_rate"], kl)
        state["opt"] = optim.set_hyperparams(state["opt"], learning_rate=lr)
        updates, state["opt"] = opt.update(grads, state["opt"], state["params"])
        state["params"] = optim.apply_updates(state["params"], updates)
        return optim.global_norm(updates)

    fn = mx.compile(step, inputs=state, outputs=state) if compiled else step
    out = []
    for i, g in enumerate(_grads(scales=(0.3, 3.0))):
        if i == 12:  # written from outside between steps: an input array, no retrace
            state["opt"] = optim.set_hyperparams(state["opt"], weight_decay=0.5)
        norm = fn(tree_map(mx.array, g), mx.array(KLS[i]))
        mx.eval(norm, state)
        out.append(_np(state["params"]))
    return out, state, len(traces)


def test_compiled_matches_uncompiled_and_optax():
    got, cstate, n_traces = _compiled_run(True)
    eager, estate, _ = _compiled_run(False)
    _assert_same(got, eager)
    assert n_traces == 1, f"compiled step traced {n_traces} times"
    assert int(cstate["opt"][1]["count"]) == STEPS
    assert float(cstate["opt"][1]["hyperparams"]["learning_rate"]) == pytest.approx(
        float(estate["opt"][1]["hyperparams"]["learning_rate"]), rel=1e-6)

    def edit_optax(i, s):
        hp = s[1].hyperparams
        if i == 12:
            hp["weight_decay"] = jnp.asarray(0.5, jnp.float32)
        hp["learning_rate"] = _kl_rule(jnp, hp["learning_rate"], jnp.asarray(KLS[i]))
        return s

    ref = optax.chain(optax.clip_by_global_norm(1.0),
                      optax.inject_hyperparams(optax.adamw, static_args="mask")(
                          learning_rate=1e-3, weight_decay=0.1, mask=_decay_mask))
    want, _ = _run_optax(ref, _params(), _grads(scales=(0.3, 3.0)), edit_optax)
    _assert_same(got, want)


def test_state_is_a_plain_mlx_pytree():
    """Masked, injected and chained states: only dicts/tuples of arrays; mlx.utils traverses them."""
    import mlx.utils

    opt = optim.chain(
        optim.clip_by_global_norm(1.0),
        optim.masked(optim.scale_by_adam(), PREFIX_MASK),
        optim.inject_hyperparams(optim.adamw)(learning_rate=optim.linear_schedule(1e-2, 0.0, 10),
                                              mask=_decay_mask(_params())))
    params = tree_map(mx.array, _params())
    state = opt.init(params)
    _, state = opt.update(tree_map(mx.array, _grads()[0]), state, params)
    flat = mlx.utils.tree_flatten(state)
    assert flat and all(isinstance(v, mx.array) for _, v in flat)
    assert not any(k.startswith("1.inner_state.mu.log_std") for k, _ in flat)  # hidden by the mask
    ndims = mlx.utils.tree_map(lambda x: x.ndim, state)
    assert ndims[1]["inner_state"]["mu"]["log_std"] == optim.MASKED
    assert [k for k, _ in mlx.utils.tree_flatten(ndims)] == [k for k, _ in flat]


def test_low_precision_params_keep_dtype():
    """bfloat16 params stay bfloat16. As in optax, injected hyperparameters default to the params' dtype,
    where b2=0.999 rounds to 1 (NaN updates): pass hyperparam_dtype=float32 for low-precision params."""
    ones = {"w": mx.ones((3, 2), dtype=mx.bfloat16), "b": mx.zeros((2,), dtype=mx.bfloat16)}
    assert optim.inject_hyperparams(optim.adam)(1e-2).init(ones)["hyperparams"]["b2"].dtype == mx.bfloat16
    for opt in (optim.adamw(1e-2, weight_decay=0.1),
                optim.inject_hyperparams(optim.adamw, hyperparam_dtype=mx.float32)(1e-2, weight_decay=0.1)):
        params = ones
        state = opt.init(params)
        for _ in range(3):
            updates, state = opt.update(tree_map(mx.ones_like, params), state, params)
            params = optim.apply_updates(params, updates)
        mx.eval(params, state)
        assert all(x.dtype == mx.bfloat16 for x in tree_leaves(params))
        assert 0.9 < float(params["w"][0, 0]) < 1.0
