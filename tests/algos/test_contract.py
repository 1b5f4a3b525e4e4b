"""The algorithm contract (``unilab_jax.algos.contract``) and the registry's ``info``: every registered
declaration satisfies the Protocols, ``info`` reports each algorithm's family and capabilities, the hooks'
defaults live in one place, and an off-policy algorithm is added by a declaration and a ``register`` call."""

from __future__ import annotations

import dataclasses
import pathlib
import re
from types import SimpleNamespace

import numpy as np
import pytest

from tasks.base import TaskSpec
from unilab_jax import algos
from unilab_jax.algos import contract

ROOT = pathlib.Path(__file__).resolve().parents[2]
JAX_MLX = ("jax", "mlx")
# name -> (family, update, sync, buffer, platforms, images, prior data, flow policy)
EXPECTED = {
    "ppo": ("on_policy", "ppo", "lockstep", "trajectory", JAX_MLX, False, False, False),
    "appo": ("on_policy", "ppo", "async", "trajectory", JAX_MLX, False, False, False),
    "him_ppo": ("on_policy", "ppo", "lockstep", "trajectory", ("jax",), False, False, False),
    "sac": ("off_policy", "sac", "async", "replay", JAX_MLX, True, False, False),
    "td3": ("off_policy", "td3", "async", "replay", JAX_MLX, False, False, False),
    "fastsac": ("off_policy", "sac", "async", "replay", JAX_MLX, False, False, False),
    "flashsac": ("off_policy", "sac", "async", "replay", JAX_MLX, False, False, False),
    "rlpd": ("off_policy", "sac", "async", "replay", JAX_MLX, True, True, False),
    "rlpd_flow": ("off_policy", "sac", "async", "replay", JAX_MLX, True, True, True),
    "sacflow": ("off_policy", "sac", "async", "replay", JAX_MLX, True, False, True),
    "hora_teacher": ("on_policy", "ppo", "lockstep", "trajectory", ("jax",), False, False, False),
    "hora_student": ("distillation", "adaptation", "async", "trajectory", ("jax",), False, False, False),
}


def test_every_registered_algorithm_is_expected_here():
    assert sorted(EXPECTED) == algos.names()


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_info_reports_family_and_capabilities(name):
    info = algos.info(name)
    got = (info.family, info.update, info.sync, info.buffer, info.platforms, info.images, info.prior_data,
           info.flow_policy)
    assert got == EXPECTED[name]
    assert info.name == name and info.module == algos.get(name).__name__
    assert algos.info(algos.get(name)) == info == algos.info(info.module)  # by module or its path too


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_every_declaration_satisfies_the_protocol(name):
    decl = algos.get(name)
    info = algos.info(name)
    assert isinstance(decl, contract.RolloutDeclaration) and isinstance(decl, contract.Declaration)
    assert not contract.missing(decl, contract.DECLARATION_ATTRIBUTES)
    assert decl.SYNC in contract.SYNC_KINDS and decl.BUFFER in contract.BUFFER_KINDS
    config = decl.Config()
    assert dataclasses.is_dataclass(config) and isinstance(config, contract.LoopConfig)
    if info.buffer == "replay":
        assert isinstance(config, contract.ReplayLoopConfig)
    # The SAC-family learner runs exactly the declarations with its losses.
    sac_family = info.update == "sac"
    assert isinstance(decl, contract.SACFamilyDeclaration) == sac_family
    assert (algos._LEARNERS[name] == algos._SAC_FAMILY) == sac_family
    # A capability and what it needs go together.
    fields = {f.name for f in dataclasses.fields(config)}
    assert info.prior_data == ({"prior_dir", "prior_fraction"} <= fields)
    if info.images:
        assert {"encoder_channels", "encoder_strides", "feature_dim", "image_pad"} <= fields
    # Every hook a declaration defines has the hook's kind.
    hooks = contract.hooks(decl)
    for field in dataclasses.fields(hooks):
        value = getattr(hooks, field.name)
        assert value is None or isinstance(value, field.default.__class__) or callable(value), field.name


def test_hooks_defaults_and_declared_hooks():
    bare = contract.hooks(SimpleNamespace(SYNC="async", BUFFER="replay", extras=dict, act=None))
    assert (bare.noise_hold_steps, bare.noise_dim(3), bare.learner_noise_dim(None, 3)) == (1, 3, 3)
    assert (bare.images, bare.prior_data, bare.project_params, bare.reward_scale, bare.critic_noise_shape) == (
        False, False, None, None, None)
    assert bare.actor_every(None) == 1 and bare.check_run("jax", None, None) is None
    assert bare.project({"w": 1}) == {"w": 1}
    flash, flow, rlpd = (contract.hooks(algos.get(n)) for n in ("flashsac", "sacflow", "rlpd"))
    assert flash.noise_hold_steps == 4 and flash.project_params is not None and flash.reward_scale is not None
    cfg = algos.get("sacflow").Config(flow_steps=3)
    assert flow.noise_dim(2) == 17 * 2 and flow.learner_noise_dim(cfg, 2) == 4 * 2
    rcfg = algos.get("rlpd").Config(num_critics=5, actor_every=3)
    assert rlpd.critic_noise_shape(rcfg) == (5,) and rlpd.actor_every(rcfg) == 3
    # RLPD Flow: the flow's noise (workers and learner) and RLPD's critic noise and delayed actor, both from its config.
    both = contract.hooks(algos.get("rlpd_flow"))
    fcfg = algos.get("rlpd_flow").Config(flow_steps=3, num_critics=5, actor_every=3)
    assert both.noise_dim(2) == 17 * 2 and both.learner_noise_dim(fcfg, 2) == 4 * 2
    assert both.critic_noise_shape(fcfg) == (5,) and both.actor_every(fcfg) == 3
    assert both.prior_data and both.images
    assert (fcfg.target_entropy_per_dim, fcfg.num_critics, fcfg.init_alpha) == (0.0, 5, 1.0)  # SAC Flow's, RLPD's
    with pytest.raises(ValueError, match="platform"):
        contract.hooks(algos.get("him_ppo")).check_run("mlx", None, None)


def test_nothing_probes_a_declaration_for_a_hook():
    """The hooks are read through ``contract.hooks`` and capabilities through ``algos.info`` only."""
    hook = "|".join(list(contract.HOOK_NAMES) + ["temperature_loss", "prior_dir"])
    probe = re.compile(rf"""(getattr|hasattr)\([^)]*["']({hook})["']""")
    found = [f"{p.relative_to(ROOT)}:{i}" for package in ("unilab_jax", "unilab_mlx", "tasks")
             for p in sorted((ROOT / package).rglob("*.py")) if p.name != "contract.py"
             for i, line in enumerate(p.read_text().splitlines(), 1) if probe.search(line)]
    assert not found, found


@pytest.mark.parametrize("cls, kwargs, message", [
    ("sac", dict(init_alpha=0.0), "SACConfig: init_alpha must be positive"),
    ("sac", dict(tau=0.0), "SACConfig: need 0 <= gamma <= 1 and 0 < tau <= 1"),
    ("td3", dict(policy_delay=0), "TD3Config: policy_delay must be >= 1"),
    ("fastsac", dict(num_atoms=1), "FastSACConfig: need num_atoms >= 2 and v_min < v_max"),
    ("flashsac", dict(v_min=1.0, v_max=0.0), "FlashSACConfig: need num_atoms >= 2"),
    ("rlpd", dict(subset_size=20), "RLPDConfig: need 1 <= subset_size <= num_critics"),
    ("sacflow", dict(flow_steps=0), "SACFlowConfig: flow_steps must be in"),
    ("rlpd_flow", dict(flow_steps=0, subset_size=20), "RLPDFlowConfig: flow_steps must be in [1, 16], got 0; need 1 "
     "<= subset_size"),
    ("td3", dict(compute_dtype="float16"), "TD3Config: compute_dtype must be"),
])
def test_each_config_validates_its_own_fields(cls, kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        algos.get(cls).Config(**kwargs)


def test_every_problem_in_one_message():
    with pytest.raises(ValueError) as e:
        algos.get("rlpd").Config(init_alpha=-1.0, feature_dim=0, actor_every=0)
    assert str(e.value).startswith("RLPDConfig: ")
    assert all(s in str(e.value) for s in ("init_alpha", "feature_dim", "actor_every"))


def test_td3_needs_nothing_of_sac():
    source = (ROOT / "unilab_jax/algos/offpolicy/td3.py").read_text()
    assert "offpolicy.sac" not in source and "import sac" not in source


def _batch(rng: np.random.Generator, u: int, b: int, obs: int, a: int) -> dict:
    o = rng.normal(size=(u, b, obs)).astype(np.float32)
    return {"obs": o, "critic_obs": o, "action": rng.uniform(-1, 1, (u, b, a)).astype(np.float32),
            "reward": rng.normal(size=(u, b)).astype(np.float32), "next_obs": o, "next_critic_obs": o,
            "terminated": np.zeros((u, b), bool), "truncated": np.zeros((u, b), bool)}


@pytest.mark.parametrize("platform", JAX_MLX)
def test_an_offpolicy_algorithm_needs_only_a_declaration_and_a_register_call(monkeypatch, platform):
    if platform == "jax":
        jax = pytest.importorskip("jax")
        key = jax.random.PRNGKey(0)
    else:
        mx = pytest.importorskip("mlx.core")
        key = mx.random.key(0)
    for table in ("_ALGORITHMS", "_LEARNERS", "_KINDS"):
        monkeypatch.setattr(algos, table, dict(getattr(algos, table)))
    learners = {p: f"unilab_jax.algos.offpolicy.learner_{p}:SACFamilyLearner" for p in JAX_MLX}
    algos.register("tiny_sac", "tiny_sac_algo", learners, update="sac")

    info = algos.info("tiny_sac")
    assert (info.family, info.update, info.sync, info.buffer, info.platforms, info.images, info.prior_data) == (
        "off_policy", "sac", "async", "replay", JAX_MLX, False, False)
    decl = algos.get("tiny_sac")
    assert isinstance(decl, contract.SACFamilyDeclaration)
    with pytest.raises(ValueError, match="MeanQSACConfig: actor_q must be"):
        decl.Config(actor_q="max")
    obs, a, u, b = 3, 2, 2, 8
    spec = TaskSpec("tiny", obs, obs, a, 1, 0.02, ())
    config = dataclasses.replace(decl.Config(), actor_hidden=(8,), critic_hidden=(8,), batch_size=b,
                                 updates_per_call=u)
    learner = algos.make_learner("tiny_sac", platform, config, spec)
    assert type(learner) is type(decl.make_learner(platform, config, spec))
    state = learner.init(key)
    state, metrics = learner.update(state, _batch(np.random.default_rng(0), u, b, obs, a))
    assert int(np.asarray(state.steps)) == u
    assert {"critic_loss", "actor_loss", "alpha", "alpha_loss"} <= set(metrics)
    assert all(np.isfinite(np.asarray(v)).all() for v in metrics.values())
