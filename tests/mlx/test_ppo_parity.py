"""The MLX PPO/APPO learner against the JAX one: same state in, same minibatch permutations, one
update on both, same parameters / optimizer state / normalizer / learning rate / metrics out.

The JAX state is warmed up by one update first (non-trivial Adam moments, adapted learning rate,
normalizer statistics that the loss actually uses), converted leaf by leaf with
``learner_mlx.state_from_numpy``, and the JAX epoch permutations (drawn from the JAX state's
key exactly as ``ppo_jax`` does) are injected into the MLX update through ``perms=``. A negative
control (the same update with other permutations) shows the comparison can fail.
"""

from __future__ import annotations

import numpy as np
import pytest

mx = pytest.importorskip("mlx.core")

from compile_options import FAST_COMPILE  # noqa: E402
from mlx_helpers import assert_runs_without_jax  # noqa: E402
from mlx_helpers import leaf_errors as _leaf_errors  # noqa: E402

from tasks.base import TaskSpec  # noqa: E402
from unilab_jax import nets  # noqa: E402
from unilab_jax.algos.ppo import appo, ppo  # noqa: E402
from unilab_jax.algos.ppo import learner_mlx as mlx_ppo  # noqa: E402
from unilab_jax.core import distributions  # noqa: E402

SPEC = TaskSpec(name="t", obs_dim=6, critic_obs_dim=8, action_dim=3, episode_length=50, ctrl_dt=0.02,
                reward_terms=("r",))
T, B = 8, 16
RTOL = 1e-4  # max |mlx - jax| / max |jax| per leaf


def _config(**kw) -> ppo.PPOConfig:
    base = dict(actor_hidden=(32, 32), critic_hidden=(32, 32), num_epochs=2, num_minibatches=4)
    return ppo.PPOConfig(**{**base, **kw})


def _batch(seed: int, weights: dict) -> dict[str, np.ndarray]:
    """A [T, B] numpy batch acted by ``weights`` (numpy) with a perturbed behaviour policy (so the KL
    and importance ratios are clearly non-zero), un-normalised observations and some episode ends."""
    rng = np.random.default_rng(seed)
    f32 = lambda x: np.asarray(x, np.float32)
    obs = f32(2.0 + 3.0 * rng.normal(size=(T, B, SPEC.obs_dim)))
    critic_obs = f32(1.0 - 2.0 * rng.normal(size=(T, B, SPEC.critic_obs_dim)))
    next_critic_obs = f32(critic_obs + 0.3 * rng.normal(size=critic_obs.shape))
    noise = f32(rng.normal(size=(T * B, SPEC.action_dim)))
    action, ex = ppo.act(weights, obs.reshape(T * B, -1), noise)
    mean = f32(ex["mean"] + 0.1 * rng.normal(size=ex["mean"].shape))
    log_std = f32(ex["log_std"] + 0.1 * rng.normal(size=ex["log_std"].shape))
    log_prob = distributions.gaussian_log_prob(action, mean, log_std)
    terminated = rng.random((T, B)) < 0.05
    truncated = (rng.random((T, B)) < 0.08) & ~terminated
    assert terminated.any() and truncated.any()
    return {"obs": obs, "critic_obs": critic_obs, "next_critic_obs": next_critic_obs,
            "action": f32(action).reshape(T, B, -1), "reward": f32(rng.normal(size=(T, B))),
            "terminated": terminated, "truncated": truncated, "log_prob": f32(log_prob).reshape(T, B),
            "mean": mean.reshape(T, B, -1), "log_std": log_std.reshape(T, B, -1)}


def _to_mlx(batch: dict) -> dict:
    return {k: mx.array(v) for k, v in batch.items()}


def _setup(use_vtrace: bool, config: ppo.PPOConfig):
    """Warmed-up JAX state, its MLX copy (and an MLX template state), the next batch and the JAX
    epoch permutations."""
    jax = pytest.importorskip("jax")
    import jax.numpy as jnp

    from unilab_jax.algos.ppo.learner_jax import Learner as JaxLearner

    jl = JaxLearner(config, SPEC, use_vtrace=use_vtrace, compiler_options=FAST_COMPILE)
    ml = mlx_ppo.Learner(config, SPEC, use_vtrace=use_vtrace)
    js = jl.init(jax.random.PRNGKey(0))
    warm = _batch(1, nets.to_numpy(JaxLearner.weights(js)))
    js, _ = jl.update(js, {k: jnp.asarray(v) for k, v in warm.items()})
    batch = _batch(2, nets.to_numpy(JaxLearner.weights(js)))
    # ppo_jax: keys = split(state.key, num_epochs + 1); epoch e permutes with keys[e + 1].
    keys = jax.random.split(js.key, config.num_epochs + 1)
    perms = np.stack([np.asarray(jax.random.permutation(k, T * B)) for k in keys[1:]])
    like = ml.init(mx.random.key(0))
    ms = mlx_ppo.state_from_numpy(js, like)
    return jl, ml, js, ms, like, batch, perms


CASES = {
    # name: (use_vtrace, config overrides, inject the JAX permutations)
    "ppo-4mb-kl-down": (False, dict(desired_kl=0.01, learning_rate=1e-2), True),
    "appo-4mb-kl-down": (True, dict(desired_kl=0.01, learning_rate=1e-2), True),
    "ppo-3mb-kl-up-noclip": (False, dict(desired_kl=1.0, learning_rate=1e-4, num_minibatches=3,
                                         value_clip=0.0), True),
    "appo-1mb-own-perm": (True, dict(desired_kl=0.01, learning_rate=1e-2, num_minibatches=1), False),
    # the schedules a quarter of the way (the warm-up update used T * B of 4 T B steps): rate and std bound
    "ppo-linear-lr-std-bound": (False, dict(lr_schedule="linear", learning_rate=1e-2, final_learning_rate=1e-3,
                                            final_std=0.5, schedule_steps=4 * T * B, ent_coef=1.0), True),
}


@pytest.mark.parametrize("case", list(CASES))
def test_one_update_matches_jax(case):
    import jax
    import jax.numpy as jnp

    use_vtrace, overrides, inject = CASES[case]
    config = _config(**overrides)
    jl, ml, js, ms, like, batch, perms = _setup(use_vtrace, config)

    js2, jm = jl.update(js, {k: jnp.asarray(v) for k, v in batch.items()})
    js2, jm = jax.device_get((js2, jm))
    ms2, mm = ml.update(ms, _to_mlx(batch), perms=perms if inject else None)
    got = mlx_ppo.state_to_numpy(ms2)
    # The optax state read into the MLX optimizer's layout, so the two compare path by path.
    want = mlx_ppo.state_to_numpy(mlx_ppo.state_from_numpy(js2, like))

    errors = _leaf_errors(got, want)  # params, Adam moments, hyperparameters, normalizers
    worst = max(errors, key=errors.get)
    print(f"{case}: max relative difference JAX vs MLX {errors[worst]:.2e} at {worst}")
    bad = {p: e for p, e in errors.items() if e > RTOL}
    assert not bad, f"MLX differs from JAX beyond {RTOL}: {bad}"

    lr_jax = float(js2.opt_state[1].hyperparams["learning_rate"])
    lr_mlx = float(mlx_ppo.learning_rate(ms2.opt_state))
    assert lr_mlx == pytest.approx(lr_jax, rel=1e-5)
    if config.final_std > 0:  # the entropy bonus pushes the std up to its bound, 1 - 0.5 / 4
        np.testing.assert_allclose(np.exp(got.params["log_std"]), 0.875, rtol=1e-5)
    if config.desired_kl > 0:  # the KL rule (or the schedule) moved the rate during this update
        assert lr_mlx != pytest.approx(float(mlx_ppo.learning_rate(ms.opt_state)), rel=1e-3)
    assert int(got.opt_state[1]["count"]) == int(js2.opt_state[1].count)
    assert int(got.updates) == int(js2.updates) == 2
    assert not np.array_equal(np.asarray(ms2.key), np.asarray(ms.key))  # the key advanced

    assert set(mm) == set(jm)
    for k in jm:
        assert float(mm[k]) == pytest.approx(float(jm[k]), rel=1e-4, abs=1e-6), k

    # Negative controls, so the comparison above can fail: the update moves the parameters far
    # beyond the tolerance, and (with several minibatches) other permutations give other results.
    moved = _leaf_errors({"params": mlx_ppo.state_to_numpy(ms).params}, {"params": got.params})
    assert max(moved.values()) > 100 * RTOL, moved
    if config.num_minibatches > 1:
        other, _ = ml.update(ms, _to_mlx(batch), perms=perms[:, ::-1])
        control = _leaf_errors({"params": mlx_ppo.state_to_numpy(other).params}, {"params": got.params})
        assert max(control.values()) > 100 * RTOL, control


def test_state_from_numpy_names_mismatched_leaf():
    ml = mlx_ppo.Learner(_config(), SPEC)
    like = ml.init(mx.random.key(0))
    src = mlx_ppo.state_to_numpy(like)
    src.params["critic"][1]["w"] = np.zeros((3, 3), np.float32)
    with pytest.raises(ValueError, match="params/critic/1/w"):
        mlx_ppo.state_from_numpy(src, like)
    src = mlx_ppo.state_to_numpy(like)
    del src.opt_state[1]["inner_state"][0]["nu"]
    with pytest.raises(KeyError, match="opt_state/1/inner_state/0/nu"):
        mlx_ppo.state_from_numpy(src, like)


@pytest.mark.parametrize("use_vtrace", [False, True], ids=["ppo", "appo"])
def test_updates_improve_objective(use_vtrace):
    """On one fixed batch, every MLX update lowers the loss it optimises (the PPO/APPO loss with the
    targets and normalizers at the start of that update), and over several updates the critic
    learns the reward. gamma = 0 with a learnable reward (a function of the critic observation)
    makes the value targets reachable on random data."""
    config = _config(desired_kl=0.0, learning_rate=3e-3, gamma=0.0)
    ml = mlx_ppo.Learner(config, SPEC, use_vtrace=use_vtrace)
    state = ml.init(mx.random.key(3))
    raw = _batch(4, nets.to_numpy(mlx_ppo.Learner.weights(state)))
    raw["reward"] = (0.5 * raw["critic_obs"][..., 0] - 0.3 * raw["critic_obs"][..., 1]).astype(np.float32)
    batch = _to_mlx(raw)

    def value_error(s: mlx_ppo.TrainState) -> float:
        v = ppo.value(s.params, s.critic_norm, batch["critic_obs"])
        return float(mx.mean(mx.square(v - batch["reward"])))

    errors = [value_error(state)]
    for _ in range(6):
        flat, _ = ml._targets_fn(state.params, state.obs_norm, state.critic_norm, batch)

        def objective(params: dict, s: mlx_ppo.TrainState = state, flat: dict = flat) -> float:
            total, _ = ppo.loss(params, s.obs_norm, s.critic_norm, flat, config, asymmetric_clip=use_vtrace)
            return float(total)

        before = objective(state.params)
        state, metrics = ml.update(state, batch)
        assert all(np.isfinite(float(v)) for v in metrics.values()), metrics
        assert objective(state.params) < before - 0.01, (before, objective(state.params))
        errors.append(value_error(state))
    assert errors[-1] < 0.1 * errors[0], errors
    assert int(state.updates) == 6


def test_make_learner_mlx():
    for module, vt in ((ppo, False), (appo, True)):
        learner = module.make_learner("mlx", _config(), SPEC)
        assert isinstance(learner, mlx_ppo.Learner) and learner.use_vtrace is vt


NO_JAX = """
import sys
sys.modules['jax'] = None
sys.modules['optax'] = None
import mlx.core as mx
import numpy as np
from tasks.base import TaskSpec
from unilab_jax.algos.ppo import appo, ppo
spec = TaskSpec(name='t', obs_dim=6, critic_obs_dim=8, action_dim=3, episode_length=50, ctrl_dt=0.02,
                reward_terms=('r',))
cfg = ppo.PPOConfig(actor_hidden=(16,), critic_hidden=(16,), num_epochs=2, num_minibatches=2)
rng = np.random.default_rng(0)
T, B = 4, 8
f = lambda *s: mx.array(rng.normal(size=s).astype(np.float32))
batch = dict(obs=f(T, B, 6), critic_obs=f(T, B, 8), next_critic_obs=f(T, B, 8), action=f(T, B, 3),
             reward=f(T, B), terminated=mx.array(rng.random((T, B)) < 0.1),
             truncated=mx.array(rng.random((T, B)) < 0.1), log_prob=f(T, B), mean=f(T, B, 3),
             log_std=mx.zeros((T, B, 3)))
for module in (ppo, appo):
    learner = module.make_learner('mlx', cfg, spec)
    state = learner.init(mx.random.key(0))
    state, metrics = learner.update(state, batch)
    assert int(state.updates) == 1
    assert all(np.isfinite(float(v)) for v in metrics.values()), metrics
    w = learner.weights(state)
    assert set(w) == {'actor', 'log_std', 'obs_norm'}
"""


def test_runs_without_jax():
    assert_runs_without_jax(NO_JAX)
