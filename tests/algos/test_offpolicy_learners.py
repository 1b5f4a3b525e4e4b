"""JAX learners of SAC, TD3, FastSAC and FlashSAC: one jitted update, Polyak, projection, wiring, and
learning a contextual bandit.

One learner per algorithm (small networks; compiled at optimisation level 0 to keep CPU compile
time low) is shared by all tests of that algorithm, so each update function compiles once.
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
from unilab_jax.algos.offpolicy import flashsac  # noqa: E402
from unilab_jax.algos.offpolicy import learner_jax as offpolicy_jax  # noqa: E402

OBS, A, B = 4, 2, 128
SPEC = TaskSpec("bandit", OBS, OBS, A, 1, 0.02, ())
COMMON = dict(actor_hidden=(64, 64), critic_hidden=(64, 64), batch_size=B, actor_learning_rate=1e-3,
              critic_learning_rate=1e-3)
# name -> (config overrides, learner calls for the bandit test). U * calls = gradient steps.
SETUPS = {
    "sac": (dict(updates_per_call=1, alpha_learning_rate=1e-3), 300),
    "td3": (dict(updates_per_call=2), 150),
    "fastsac": (dict(updates_per_call=10, alpha_learning_rate=1e-3, num_atoms=51, v_min=-10.0, v_max=1.0,
                     init_alpha=0.05), 30),
    "flashsac": (dict(updates_per_call=10, alpha_learning_rate=1e-3, num_atoms=51, gamma=0.5,
                      actor_learning_rate=3e-3, critic_learning_rate=3e-3), 30),
}
NAMES = tuple(SETUPS)
_LEARNERS: dict = {}

# The bandit: reward = -||a - f(obs)||^2, every transition terminal.
_WF = np.random.default_rng(123).normal(size=(OBS, A)).astype(np.float32) * 0.7


def _best_action(obs: np.ndarray) -> np.ndarray:
    return np.tanh(obs @ _WF)


def _batch(rng: np.random.Generator, u: int, terminated: float = 1.0) -> dict:
    obs = rng.normal(size=(u, B, OBS)).astype(np.float32)
    action = rng.uniform(-1, 1, (u, B, A)).astype(np.float32)
    reward = -np.sum((action - _best_action(obs)) ** 2, -1).astype(np.float32)
    return {"obs": obs, "critic_obs": obs, "action": action, "reward": reward,
            "next_obs": rng.normal(size=(u, B, OBS)).astype(np.float32),
            "next_critic_obs": rng.normal(size=(u, B, OBS)).astype(np.float32),
            "terminated": np.full((u, B), bool(terminated)), "truncated": np.zeros((u, B), bool)}


def _learner(name: str):
    if name not in _LEARNERS:
        mod = algos.get(name)
        cfg = dataclasses.replace(mod.Config(), **{**COMMON, **SETUPS[name][0]})
        if name == "td3":
            _LEARNERS[name] = (mod, cfg, offpolicy_jax.TD3Learner(cfg, SPEC, compiler_options=FAST_COMPILE))
        else:
            _LEARNERS[name] = (mod, cfg, offpolicy_jax.SACFamilyLearner(mod, cfg, SPEC,
                                                                        compiler_options=FAST_COMPILE))
    return _LEARNERS[name]


def _np(tree):
    return jax.tree_util.tree_map(lambda x: np.array(x), tree)


def _leaves_differ(a, b) -> bool:
    return any(not np.array_equal(x, y) for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)))


@pytest.mark.parametrize("name", NAMES)
def test_make_learner_builds_the_jax_learner(name):
    mod = algos.get(name)
    learner = mod.make_learner("jax", mod.Config(actor_hidden=(8,), critic_hidden=(8,)), SPEC)
    assert isinstance(learner, offpolicy_jax.TD3Learner if name == "td3" else offpolicy_jax.SACFamilyLearner)


@pytest.mark.parametrize("name", NAMES)
def test_one_update_runs_changes_params_and_does_not_retrace(name):
    mod, cfg, learner = _learner(name)
    rng = np.random.default_rng(0)
    state = learner.init(jax.random.PRNGKey(0))
    assert isinstance(state, tuple) and hasattr(state, "_fields")  # ONE NamedTuple pytree
    before = _np(state)
    state, metrics = learner.update(state, _batch(rng, cfg.updates_per_call, terminated=0.0))
    assert metrics and all(np.isfinite(float(v)) for v in metrics.values()), metrics
    assert _leaves_differ(before.actor, _np(state.actor)) and _leaves_differ(before.critic, _np(state.critic))
    assert int(state.steps) == cfg.updates_per_call
    state, metrics = learner.update(state, _batch(rng, cfg.updates_per_call, terminated=0.0))
    assert all(np.isfinite(float(v)) for v in metrics.values())
    assert learner.trace_count == 1, "update retraced on a second call with same-shaped inputs"
    # What the workers get: numpy weights that ``act`` runs on.
    weights = nets.to_numpy(learner.weights(state))
    action, extras = mod.act(weights, np.zeros((3, OBS), np.float32), np.ones((3, A), np.float32), False)
    assert action.shape == (3, A) and action.dtype == np.float32 and extras == {}


def test_sac_polyak_uses_tau():
    _, cfg, learner = _learner("sac")
    assert cfg.updates_per_call == 1
    state = learner.init(jax.random.PRNGKey(1))
    # Start the target away from the critic so the average is visible.
    state = state._replace(target_critic=jax.tree_util.tree_map(lambda x: x + 1.0, state.target_critic))
    target0 = _np(state.target_critic)
    state, _ = learner.update(state, _batch(np.random.default_rng(1), 1, terminated=0.0))
    expected = jax.tree_util.tree_map(lambda t, c: (1 - cfg.tau) * t + cfg.tau * c, target0, _np(state.critic))
    for got, want in zip(jax.tree_util.tree_leaves(_np(state.target_critic)), jax.tree_util.tree_leaves(expected)):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_td3_polyak_uses_tau_and_waits_for_the_policy_delay():
    _, cfg, learner = _learner("td3")
    assert cfg.updates_per_call == 2 and cfg.policy_delay == 2
    state = learner.init(jax.random.PRNGKey(2))
    bump = lambda t: jax.tree_util.tree_map(lambda x: x + 1.0, t)
    state = state._replace(target_critic=bump(state.target_critic), target_actor=bump(state.target_actor))
    before = _np(state)
    # Steps 0 and 1: the critic moves twice, the actor and both targets once (after step 1).
    state, metrics = learner.update(state, _batch(np.random.default_rng(2), 2, terminated=0.0))
    assert float(metrics["actor_steps"]) == 1.0
    after = _np(state)
    for target, online in (("target_critic", "critic"), ("target_actor", "actor")):
        expected = jax.tree_util.tree_map(lambda t, c: (1 - cfg.tau) * t + cfg.tau * c, getattr(before, target),
                                          getattr(after, online))
        for got, want in zip(jax.tree_util.tree_leaves(getattr(after, target)), jax.tree_util.tree_leaves(expected)):
            np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_flashsac_weights_stay_unit_norm_after_updates():
    _, cfg, learner = _learner("flashsac")
    state = learner.init(jax.random.PRNGKey(3))
    before = _np(state)
    state, _ = learner.update(state, _batch(np.random.default_rng(3), cfg.updates_per_call, terminated=0.0))
    for net in ("actor", "critic", "target_critic"):
        params = getattr(_np(state), net)
        for i, layer in enumerate(params):
            np.testing.assert_allclose(np.linalg.norm(layer["w"], axis=-2), 1.0, rtol=1e-5, err_msg=f"{net}[{i}]")
        assert _leaves_differ(getattr(before, net), params)
    # The projection is what keeps them there: an unprojected Adam step leaves the unit sphere.
    moved = jax.tree_util.tree_map(lambda x: x + 0.01, state.actor)
    assert not np.allclose(np.linalg.norm(np.asarray(moved[0]["w"]), axis=-2), 1.0, rtol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(flashsac.project_params(moved)[0]["w"]), axis=-2), 1.0,
                               rtol=1e-5)


@pytest.mark.parametrize("name", ["sac", "flashsac"])
def test_learner_target_wiring_on_terminal_transitions(name):
    """Terminal transitions: the target is the (normalised) reward exactly, inside the jitted update."""
    _, cfg, learner = _learner(name)
    state = learner.init(jax.random.PRNGKey(4))
    batch = _batch(np.random.default_rng(4), cfg.updates_per_call, terminated=1.0)
    state, metrics = learner.update(state, batch)
    reward = batch["reward"].astype(np.float64)
    scale = 1.0
    if name == "flashsac":  # reward statistics come from the first minibatch, before the steps
        r0 = reward[0]
        scale = np.sqrt(np.mean(r0) ** 2 + np.var(r0)) / (1 - cfg.gamma)
        assert float(metrics["reward_scale"]) == pytest.approx(scale, rel=1e-4)
    assert float(metrics["target_mean"]) == pytest.approx(np.mean(reward / scale), rel=1e-4, abs=1e-5)


@pytest.mark.parametrize("name", NAMES)
def test_learns_a_contextual_bandit(name):
    """reward = -||a - f(obs)||^2 on uniformly random replayed actions: the greedy policy must find f."""
    mod, cfg, learner = _learner(name)
    rng = np.random.default_rng(5)
    test_obs = rng.normal(size=(512, OBS)).astype(np.float32)

    def error(state) -> float:
        action, _ = mod.act(nets.to_numpy(learner.weights(state)), test_obs, np.zeros((512, A), np.float32), True)
        return float(np.mean(np.sum((action - _best_action(test_obs)) ** 2, -1)))

    state = learner.init(jax.random.PRNGKey(5))
    start = error(state)
    for _ in range(SETUPS[name][1]):
        state, metrics = learner.update(state, _batch(rng, cfg.updates_per_call))
    final = error(state)
    assert start > 0.5 and final < 0.1, f"{name}: action error {start:.3f} -> {final:.3f}; last metrics {metrics}"
    assert learner.trace_count == 1


def test_precompile_leaves_the_first_update_nothing_to_compile(caplog):
    """``precompile`` (the trainer's compile at the start of a run) builds the very program the first update runs."""
    mod = algos.get("fastsac")
    cfg = dataclasses.replace(mod.Config(), **{**COMMON, **SETUPS["fastsac"][0]})
    learner = offpolicy_jax.SACFamilyLearner(mod, cfg, SPEC, compiler_options=FAST_COMPILE)
    state = learner.init(jax.random.PRNGKey(7))
    batch = _batch(np.random.default_rng(7), cfg.updates_per_call, terminated=0.0)
    learner.precompile(state, {k: (v.shape, v.dtype) for k, v in batch.items()})
    assert learner.trace_count == 1 and int(state.steps) == 0  # traced and compiled; the state untouched
    with jax.log_compiles(True), caplog.at_level("WARNING"):
        state, metrics = learner.update(state, batch)
        jax.block_until_ready(metrics)
    compiles = [r.getMessage() for r in caplog.records if "traced_update" in r.getMessage()]
    assert compiles == [] and learner.trace_count == 1, compiles
    assert int(state.steps) == cfg.updates_per_call


@pytest.mark.parametrize("name", ["fastsac", "td3"])
def test_flat_optimizer_takes_the_same_steps(name):
    """``flat_optimizer``: the optimizers over one flat parameter vector (one moment vector per network) give the
    parameters of the per-array optimizers after two calls, up to float32 summation order (the gradient clip's
    global norm); the MLX optimizers refuse it."""
    mod = algos.get(name)
    cfg = dataclasses.replace(mod.Config(), **COMMON, **SETUPS[name][0], max_grad_norm=1.0, weight_decay=0.1)
    batch = _batch(np.random.default_rng(5), cfg.updates_per_call)
    out = {}
    for flat in (False, True):
        c = dataclasses.replace(cfg, flat_optimizer=flat)
        learner = (offpolicy_jax.TD3Learner(c, SPEC, compiler_options=FAST_COMPILE) if name == "td3"
                   else offpolicy_jax.SACFamilyLearner(mod, c, SPEC, compiler_options=FAST_COMPILE))
        state = learner.init(jax.random.PRNGKey(0))
        for _ in range(2):
            state, _ = learner.update(state, batch)
        out[flat] = state
    moments = [x for x in jax.tree_util.tree_leaves(out[True].critic_opt) if x.size > 1]
    assert moments and all(x.ndim == 1 for x in moments)  # flat moment vectors
    for a, b in zip(jax.tree_util.tree_leaves((out[True].actor, out[True].critic)),
                    jax.tree_util.tree_leaves((out[False].actor, out[False].critic)), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)
    mlx_opt = pytest.importorskip("unilab_mlx.optim")
    from unilab_jax.algos.offpolicy import learner_common

    with pytest.raises(ValueError, match="flat_optimizer"):
        learner_common.make_optimizer(mlx_opt, 1e-3, flat=True)
