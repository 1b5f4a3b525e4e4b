"""The MLX SAC-family learners on image observations (SAC, RLPD, SAC Flow) against the JAX ones: same state in,
same fresh random pixel batch (uint8 images and next images), same noise and DrQ offsets, one update of U
gradient steps on both, same state out (encoder, target encoder, Adam moments included).

As in test_offpolicy_parity: the JAX state is warmed up by one update, moved leaf by leaf to MLX, and the draws
the JAX update makes from its key (normals, RLPD's uniforms, the DrQ offsets) are injected into the MLX update.
Negative control: other offsets (the images shifted otherwise) give another encoder.
"""

from __future__ import annotations

import dataclasses
import types

import numpy as np
import pytest

mx = pytest.importorskip("mlx.core")

from compile_options import FAST_COMPILE  # noqa: E402
from mlx_helpers import assert_runs_without_jax, leaf_errors  # noqa: E402

from tasks.base import TaskSpec  # noqa: E402
from unilab_jax.algos.offpolicy import learner_mlx as mlx_off  # noqa: E402
from unilab_jax.algos.offpolicy import rlpd, sac, sacflow  # noqa: E402

IMAGE = (12, 10, 6)  # two stacked RGB frames
SPEC = types.SimpleNamespace(**{**dataclasses.asdict(TaskSpec(name="t", obs_dim=5, critic_obs_dim=7, action_dim=2,
                                                              episode_length=50, ctrl_dt=0.02, reward_terms=("r",))),
                                "image_shape": IMAGE})
U, B = 2, 16
RTOL = 1e-4  # max |mlx - jax| / max |jax| per leaf
SMALL = dict(actor_hidden=(32,), critic_hidden=(32,), batch_size=B, updates_per_call=U, encoder_channels=(8, 8),
             encoder_strides=(2, 1), feature_dim=6, image_pad=2)
CASES = {
    "sac": (sac, dict(max_grad_norm=1.0)),
    "rlpd": (rlpd, dict(num_critics=3, subset_size=2)),
    "rlpd_delayed": (rlpd, dict(num_critics=3, subset_size=2, actor_every=2)),  # actor on every 2nd step
    "sacflow": (sacflow, dict(flow_steps=2)),
}


def _batch(seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    f32 = lambda x: np.asarray(x, np.float32)  # noqa: E731
    obs = f32(2.0 + 3.0 * rng.normal(size=(U, B, SPEC.obs_dim)))
    critic_obs = f32(1.0 - 2.0 * rng.normal(size=(U, B, SPEC.critic_obs_dim)))
    terminated = rng.random((U, B)) < 0.1
    return {"obs": obs, "critic_obs": critic_obs, "next_obs": f32(obs + 0.3 * rng.normal(size=obs.shape)),
            "next_critic_obs": f32(critic_obs + 0.3 * rng.normal(size=critic_obs.shape)),
            "action": f32(np.tanh(rng.normal(size=(U, B, SPEC.action_dim)))),
            "reward": f32(0.5 + rng.normal(size=(U, B))), "terminated": terminated,
            "truncated": (rng.random((U, B)) < 0.1) & ~terminated,
            "image": rng.integers(0, 256, (U, B, *IMAGE), dtype=np.uint8),
            "next_image": rng.integers(0, 256, (U, B, *IMAGE), dtype=np.uint8)}


def _jax_draws(learner, key) -> dict[str, np.ndarray]:
    """What the JAX update draws from ``state.key``: the same jax.random calls as ``learner_jax``."""
    import jax
    import jax.numpy as jnp

    out: dict[str, list] = {"eps_next": [], "eps": [], "u": [], "shift": []}
    for k in jax.random.split(key, U + 1)[1:]:
        ks = jax.random.split(k, learner.step_keys)
        out["eps_next"].append(jax.random.normal(ks[0], (B, learner.noise_dim), jnp.float32))
        out["eps"].append(jax.random.normal(ks[1], (B, learner.noise_dim), jnp.float32))
        if learner.critic_noise_shape is not None:
            out["u"].append(jax.random.uniform(ks[2], learner.critic_noise_shape, jnp.float32))
        out["shift"].append(jax.random.randint(ks[-1], (2, B, 2), 0, 2 * learner.config.image_pad + 1, jnp.int32))
    return {k: np.stack([np.asarray(x) for x in v]) for k, v in out.items() if v}


@pytest.mark.parametrize("name", list(CASES))
def test_one_image_update_matches_jax(name):
    jax = pytest.importorskip("jax")
    from unilab_jax.algos.offpolicy import learner_jax as offpolicy_jax

    module, overrides = CASES[name]
    config = module.Config(**{**SMALL, **overrides})
    jl = offpolicy_jax.SACFamilyLearner(module, config, SPEC, compiler_options=FAST_COMPILE)
    ml = mlx_off.SACFamilyLearner(module, config, SPEC)
    js = jl.init(jax.random.PRNGKey(0))
    like = ml.init(mx.random.key(0))
    init_err = leaf_errors(mlx_off.state_to_numpy(like), jax.device_get(js))
    assert max(init_err.values()) == 0.0, {p: e for p, e in init_err.items() if e}

    js, _ = jl.update(js, _batch(1))  # warm-up
    draws = _jax_draws(jl, js.key)
    ms = mlx_off.state_from_numpy(jax.device_get(js), like)
    batch = _batch(2)
    js2, jm = jax.device_get(jl.update(js, batch))
    ms2, mm = ml.update(ms, {k: mx.array(v) for k, v in batch.items()}, noise=draws)
    got = mlx_off.state_to_numpy(ms2)
    errors = leaf_errors(got, mlx_off.state_to_numpy(mlx_off.state_from_numpy(js2, like)))
    worst = max(errors, key=errors.get)
    print(f"{name} (images): max relative difference JAX vs MLX {errors[worst]:.2e} at {worst}")
    bad = {p: e for p, e in errors.items() if e > RTOL}
    assert not bad, f"MLX differs from JAX beyond {RTOL}: {bad}"
    assert set(mm) == set(jm)
    for k in jm:
        assert float(mm[k]) == pytest.approx(float(jm[k]), rel=1e-4, abs=1e-6), k
    assert jl.trace_count == 1

    encoder = lambda s: {"encoder": mlx_off.state_to_numpy(s).critic["encoder"]}  # noqa: E731
    moved = leaf_errors(encoder(ms), encoder(ms2))
    assert max(moved.values()) > 100 * RTOL, moved
    shifted = {**draws, "shift": (2 * config.image_pad - draws["shift"]).astype(np.int32)}  # mirrored offsets
    other, _ = ml.update(ms, {k: mx.array(v) for k, v in batch.items()}, noise=shifted)
    control = leaf_errors(encoder(other), encoder(ms2))
    assert max(control.values()) > 10 * RTOL, control
    assert ml.trace_count == (1 if ml.actor_every == 1 else 2)  # one compiled step (per actor flag), both updates


NO_JAX = """
import sys
sys.modules['jax'] = None
sys.modules['optax'] = None
import mlx.core as mx
import numpy as np
from types import SimpleNamespace
from unilab_jax import nets
from unilab_jax.algos.offpolicy import sac
spec = SimpleNamespace(name='t', obs_dim=3, critic_obs_dim=4, action_dim=2, image_shape=(10, 10, 3))
rng = np.random.default_rng(0)
U, B = 2, 4
f = lambda *s: rng.normal(size=s).astype(np.float32)
img = lambda: rng.integers(0, 256, (U, B, 10, 10, 3), dtype=np.uint8)
batch = dict(obs=f(U, B, 3), critic_obs=f(U, B, 4), next_obs=f(U, B, 3), next_critic_obs=f(U, B, 4),
             action=np.tanh(f(U, B, 2)), reward=f(U, B), terminated=np.zeros((U, B), bool),
             truncated=np.zeros((U, B), bool), image=img(), next_image=img())
config = sac.Config(actor_hidden=(8,), critic_hidden=(8,), batch_size=B, updates_per_call=U, encoder_channels=(4,),
                    encoder_strides=(2,), feature_dim=3, image_pad=1)
learner = sac.make_learner('mlx', config, spec)
state, metrics = learner.update(learner.init(mx.random.key(0)), batch)
assert int(state.steps) == U and all(np.isfinite(float(v)) for v in metrics.values()), metrics
action, _ = sac.act(nets.to_numpy(learner.weights(state)), f(B, 3), f(B, 2), image=batch['image'][0])
assert action.shape == (B, 2)
"""


def test_image_learner_and_act_run_without_jax():
    assert_runs_without_jax(NO_JAX)
