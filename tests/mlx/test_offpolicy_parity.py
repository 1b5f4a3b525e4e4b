"""The MLX off-policy learners (SAC, FastSAC, FlashSAC, RLPD, SAC Flow, RLPD Flow, TD3) against the JAX ones: same
state in, same batch, same noise, one update of U gradient steps on both, same state out.

The JAX state is warmed up by one update first (non-trivial Adam moments, normalizer and reward
statistics, a TD3 step counter off the delay phase), converted leaf by leaf with
``learner_mlx.state_from_numpy``, and the standard-normal draws the JAX update makes from
its key (re-derived here with the same ``jax.random`` calls as ``offpolicy_jax``) are injected into
the MLX update through ``noise=``. Negative controls (other noise; the update itself) show the
comparison can fail.
"""

from __future__ import annotations

import numpy as np
import pytest

mx = pytest.importorskip("mlx.core")

from compile_options import FAST_COMPILE  # noqa: E402
from mlx_helpers import assert_runs_without_jax  # noqa: E402
from mlx_helpers import leaf_errors as _leaf_errors  # noqa: E402

from tasks.base import TaskSpec  # noqa: E402
from unilab_jax.algos.offpolicy import fastsac, flashsac, rlpd, rlpdflow, sac, sacflow, td3  # noqa: E402
from unilab_jax.algos.offpolicy import learner_mlx as mlx_off  # noqa: E402

SPEC = TaskSpec(name="t", obs_dim=6, critic_obs_dim=8, action_dim=3, episode_length=50, ctrl_dt=0.02,
                reward_terms=("r",))
U, B = 3, 32
RTOL = 1e-4  # max |mlx - jax| / max |jax| per leaf
SMALL = dict(actor_hidden=(32, 32), critic_hidden=(32, 32), batch_size=B, updates_per_call=U)

CASES = {
    # name: (module, config overrides)
    "sac": (sac, dict(max_grad_norm=1.0)),
    "fastsac": (fastsac, dict(num_atoms=11, v_min=-5.0, v_max=5.0)),  # AdamW, LayerNorm critics, C51
    "flashsac": (flashsac, dict(num_atoms=11)),  # projection, reward normalisation, clipping
    "td3": (td3, dict(policy_delay=2)),
    "rlpd": (rlpd, dict(num_critics=4, subset_size=2)),  # LayerNorm ensemble, subset-min target, mean-Q actor
    "rlpd_delayed": (rlpd, dict(num_critics=3, subset_size=2, actor_every=2)),  # actor on every 2nd step only
    "sacflow": (sacflow, dict(flow_steps=2)),  # gated K-step chain; its noise is [B, (K + 1) A]
    # RLPD's ensemble and subset target, the flow's chain; every 2nd step moves the actor
    "rlpd_flow": (rlpdflow, dict(num_critics=3, subset_size=2, flow_steps=2, actor_every=2)),
}


def _config(name: str):
    module, overrides = CASES[name]
    return module, module.Config(**{**SMALL, **overrides})


def _batch(seed: int) -> dict[str, np.ndarray]:
    """A [U, B] replay batch: un-normalised observations, actions in (-1, 1), rewards off zero,
    some terminations and truncations."""
    rng = np.random.default_rng(seed)
    f32 = lambda x: np.asarray(x, np.float32)
    obs = f32(2.0 + 3.0 * rng.normal(size=(U, B, SPEC.obs_dim)))
    critic_obs = f32(1.0 - 2.0 * rng.normal(size=(U, B, SPEC.critic_obs_dim)))
    terminated = rng.random((U, B)) < 0.1
    truncated = (rng.random((U, B)) < 0.1) & ~terminated
    return {"obs": obs, "critic_obs": critic_obs,
            "next_obs": f32(obs + 0.3 * rng.normal(size=obs.shape)),
            "next_critic_obs": f32(critic_obs + 0.3 * rng.normal(size=critic_obs.shape)),
            "action": f32(np.tanh(rng.normal(size=(U, B, SPEC.action_dim)))),
            "reward": f32(0.5 + rng.normal(size=(U, B))), "terminated": terminated, "truncated": truncated}


def _jax_noise(key, name: str, width: int = SPEC.action_dim) -> dict[str, np.ndarray]:
    """The draws ``offpolicy_jax`` makes from ``state.key`` during one update (same jax.random calls)."""
    import jax
    import jax.numpy as jnp

    shape = (B, width)
    keys = jax.random.split(key, U + 1)
    if name == "td3":
        return {"eps_next": np.stack([np.asarray(jax.random.normal(k, shape, jnp.float32)) for k in keys[1:]])}
    eps_next, eps, u = [], [], []
    for k in keys[1:]:
        ks = jax.random.split(k, 3 if name.startswith("rlpd") else 2)
        eps_next.append(np.asarray(jax.random.normal(ks[0], shape, jnp.float32)))
        eps.append(np.asarray(jax.random.normal(ks[1], shape, jnp.float32)))
        if name.startswith("rlpd"):
            u.append(np.asarray(jax.random.uniform(ks[2], (CASES[name][1]["num_critics"],), jnp.float32)))
    return {"eps_next": np.stack(eps_next), "eps": np.stack(eps), **({"u": np.stack(u)} if u else {})}


def _learners(name: str):
    from unilab_jax.algos.offpolicy import learner_jax as offpolicy_jax

    module, config = _config(name)
    opts = FAST_COMPILE
    if module is td3:
        return offpolicy_jax.TD3Learner(config, SPEC, compiler_options=opts), mlx_off.TD3Learner(config, SPEC)
    return (offpolicy_jax.SACFamilyLearner(module, config, SPEC, compiler_options=opts),
            mlx_off.SACFamilyLearner(module, config, SPEC))


@pytest.mark.parametrize("name", list(CASES))
def test_one_update_matches_jax(name):
    jax = pytest.importorskip("jax")
    import jax.numpy as jnp

    jl, ml = _learners(name)
    js = jl.init(jax.random.PRNGKey(0))
    like = ml.init(mx.random.key(0))
    # Initialisation runs on numpy from the same key words on both sides: identical parameters.
    init_err = _leaf_errors(mlx_off.state_to_numpy(like), jax.device_get(js))
    assert max(init_err.values()) == 0.0, {p: e for p, e in init_err.items() if e}

    js, _ = jl.update(js, {k: jnp.asarray(v) for k, v in _batch(1).items()})  # warm-up
    noise = _jax_noise(js.key, name, getattr(jl, "noise_dim", SPEC.action_dim))
    ms = mlx_off.state_from_numpy(jax.device_get(js), like)
    batch = _batch(2)

    js2, jm = jl.update(js, {k: jnp.asarray(v) for k, v in batch.items()})
    js2, jm = jax.device_get((js2, jm))
    ms2, mm = ml.update(ms, {k: mx.array(v) for k, v in batch.items()}, noise=noise)
    got = mlx_off.state_to_numpy(ms2)
    want = mlx_off.state_to_numpy(mlx_off.state_from_numpy(js2, like))

    errors = _leaf_errors(got, want)  # networks, targets, Adam moments, log_alpha, normalizers
    worst = max(errors, key=errors.get)
    print(f"{name}: max relative difference JAX vs MLX {errors[worst]:.2e} at {worst}")
    bad = {p: e for p, e in errors.items() if e > RTOL}
    assert not bad, f"MLX differs from JAX beyond {RTOL}: {bad}"
    assert int(got.steps) == int(js2.steps) == 2 * U

    assert set(mm) == set(jm)
    for k in jm:
        assert float(mm[k]) == pytest.approx(float(jm[k]), rel=1e-4, abs=1e-6), k

    # Negative controls: the update moves the networks far beyond the tolerance, and other noise
    # (TD3: other target smoothing; SAC family: other policy samples) gives other networks.
    moved = _leaf_errors({"critic": mlx_off.state_to_numpy(ms).critic}, {"critic": got.critic})
    assert max(moved.values()) > 100 * RTOL, moved
    other, _ = ml.update(ms, {k: mx.array(v) for k, v in batch.items()},
                         noise={k: v[::-1].copy() * -1.0 for k, v in noise.items()})
    control = _leaf_errors({"critic": mlx_off.state_to_numpy(other).critic}, {"critic": got.critic})
    assert max(control.values()) > 10 * RTOL, control


def test_empty_batch_is_noop_and_no_retrace():
    _, config = _config("sac")
    ml = mlx_off.SACFamilyLearner(sac, config, SPEC)
    state = ml.init(mx.random.key(1))
    same, metrics = ml.update(state, {})
    assert same is state and metrics == {}
    batch = {k: mx.array(v) for k, v in _batch(3).items()}
    state, _ = ml.update(state, batch)
    state, _ = ml.update(state, batch)
    assert ml.trace_count == 1 and int(state.steps) == 2 * U


def test_state_from_numpy_names_mismatched_leaf():
    _, config = _config("td3")
    ml = mlx_off.TD3Learner(config, SPEC)
    like = ml.init(mx.random.key(0))
    src = mlx_off.state_to_numpy(like)
    src.critic[1]["w"] = np.zeros((3, 3), np.float32)
    with pytest.raises(ValueError, match="critic/1/w"):
        mlx_off.state_from_numpy(src, like)


NO_JAX = """
import sys
sys.modules['jax'] = None
sys.modules['optax'] = None
import mlx.core as mx
import numpy as np
from tasks.base import TaskSpec
from unilab_jax.algos.offpolicy import fastsac, flashsac, rlpd, rlpdflow, sac, sacflow, td3
spec = TaskSpec(name='t', obs_dim=6, critic_obs_dim=8, action_dim=3, episode_length=50, ctrl_dt=0.02,
                reward_terms=('r',))
rng = np.random.default_rng(0)
U, B = 2, 8
f = lambda *s: mx.array(rng.normal(size=s).astype(np.float32))
batch = dict(obs=f(U, B, 6), critic_obs=f(U, B, 8), next_obs=f(U, B, 6), next_critic_obs=f(U, B, 8),
             action=mx.tanh(f(U, B, 3)), reward=f(U, B), terminated=mx.array(rng.random((U, B)) < 0.1),
             truncated=mx.array(rng.random((U, B)) < 0.1))
small = dict(actor_hidden=(16,), critic_hidden=(16,), batch_size=B, updates_per_call=U)
for module, extra in ((sac, {}), (fastsac, dict(num_atoms=11)), (flashsac, dict(num_atoms=11)), (td3, {}),
                      (rlpd, dict(num_critics=3)), (sacflow, dict(flow_steps=2)),
                      (rlpdflow, dict(num_critics=3, flow_steps=2))):
    learner = module.make_learner('mlx', module.Config(**small, **extra), spec)
    state = learner.init(mx.random.key(0))
    state, metrics = learner.update(state, batch)
    assert int(state.steps) == U
    assert all(np.isfinite(float(v)) for v in metrics.values()), metrics
    assert 'actor' in learner.weights(state)
"""


def test_runs_without_jax():
    assert_runs_without_jax(NO_JAX)
