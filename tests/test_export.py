"""Exported actors (unilab_jax.apps.export) act exactly as the training-time numpy policy.

Every actor kind of the locomotion recipes gets the weight pytree its learner publishes (JAX learners'
``weights(init(key))`` on the recipe's task, or the HORA student's published layout), with every leaf
perturbed so that no layer is near its initial (tiny or unit) values; the ONNX graph run by onnxruntime and
the generated numpy module must then give ``algo.act(weights, obs, 0, deterministic=True)`` to 1e-5 on
random observations (a few far enough out to hit the normaliser's clip): |difference| <= 1e-5 (1 + |action|),
i.e. 1e-5 for actions in [-1, 1] (the range the tasks apply) and float32 rounding for larger raw outputs.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys

import numpy as np
import pytest

import tasks
from unilab_jax import algos, nets
from unilab_jax import xp as shim
from unilab_jax.apps import export
from unilab_jax.config import apply_overrides
from unilab_jax.core.normalizer import RunningStats

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SMALL = {"actor_hidden": (32, 24), "critic_hidden": (16,)}
HIST = {"history_len": 4}
# (algorithm, task, algorithm config, task overrides): every actor kind experiments/*.py trains on Go1/Go2/G1.
KINDS = [
    ("ppo", "go1_joystick_flat", SMALL, {}),
    ("appo", "go1_joystick_flat", SMALL, {}),
    ("sac", "go1_joystick_flat", SMALL, {}),
    ("fastsac", "go1_joystick_flat", SMALL, {}),
    ("flashsac", "go1_joystick_flat", {"actor_hidden": (32, 32, 24), "critic_hidden": (16,)}, {}),
    ("td3", "go1_joystick_flat", SMALL, {}),
    ("him_ppo", "go1_joystick_flat_hist", {**SMALL, "velocity_cols": (57, 58, 59), "estimator_hidden": (16,),
                                           "target_hidden": (16,), "latent_dim": 4, "num_prototypes": 8},
     {**HIST, "history_extrinsics": False, "history_exclude": (0, 1, 2)}),
    ("hora_teacher", "go1_joystick_flat_hist", {**SMALL, "encoder_hidden": (16,), "z_dim": 8},
     {**HIST, "history_extrinsics": True}),
]


def _perturb(tree, rng):
    """Every float leaf moved (matrices by N(0, 1/fan_in), vectors by N(0, 0.01)); normaliser statistics
    redrawn (var in [0.5, 2])."""
    if isinstance(tree, RunningStats):
        d = np.shape(tree.mean)
        return RunningStats(rng.normal(size=d).astype(np.float32), rng.uniform(0.5, 2.0, d).astype(np.float32),
                            tree.count)
    if isinstance(tree, dict):
        return {k: _perturb(v, rng) for k, v in tree.items()}
    if isinstance(tree, list | tuple):
        return type(tree)(_perturb(v, rng) for v in tree)
    a = np.asarray(tree)
    if a.dtype != np.float32:
        return tree
    scale = 1.0 / np.sqrt(a.shape[-2]) if a.ndim >= 2 else 0.1  # matrices: fan-in scaled, outputs stay O(1)
    return (a + scale * rng.standard_normal(a.shape)).astype(np.float32)


def _published(algo, task, cfg, task_cfg):
    import jax

    spec = tasks.make(task, 1, overrides=task_cfg).spec
    module = algos.get(algo)
    learner = algos.make_learner(module, "jax", apply_overrides(module.Config(), cfg), spec)
    return module, nets.to_numpy(learner.weights(learner.init(jax.random.key(0)))), spec.obs_dim


def _student():
    """The HORA student's published weights (student.py: actor, log_std, adapt, history_norm, noise_scale)."""
    from unilab_jax import nets_temporal
    from unilab_jax.algos.hora import student

    xp = shim.get("numpy")
    h, d, z, a, p = 30, 45, 8, 12, 6
    k1, k2 = xp.random.split(xp.random.key(0), 2)
    weights = {"actor": nets.init(k1, [d + z, 32, a], xp),
               "log_std": np.zeros(a, np.float32),
               "adapt": nets_temporal.adaptation_init(k2, d, z, h, xp),
               "history_norm": RunningStats(np.zeros((h, d), np.float32), np.ones((h, d), np.float32),
                                            np.float32(1.0)),
               "noise_scale": np.float32(0.0)}
    return student, weights, h * d + p


def _load_module(path):
    spec = importlib.util.spec_from_file_location(f"exported_{abs(hash(path))}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("kind", [k[0] for k in KINDS] + ["hora_student"])
def test_onnx_and_numpy_exports_match_the_training_policy(kind, tmp_path):
    import onnxruntime as ort

    if kind == "hora_student":
        module, weights, obs_dim = _student()
    else:
        module, weights, obs_dim = _published(*next(k for k in KINDS if k[0] == kind))
    rng = np.random.default_rng(1)
    weights = _perturb(weights, rng)
    obs = rng.normal(size=(64, obs_dim)).astype(np.float32)
    obs[:4] *= 30.0  # beyond the normaliser's clip
    want, _ = module.act(weights, obs, np.zeros((64, 1), np.float32), True)
    want = np.asarray(want, np.float32)
    assert np.std(want) > 0.05  # a policy that does something: the comparison is not one of constants

    graph, out = export.actor_graph(kind, weights, obs_dim)
    model = export.to_onnx(graph, out, obs_dim, want.shape[1])
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    got_onnx = session.run(["action"], {"obs": obs})[0]
    np.testing.assert_allclose(got_onnx, want, rtol=1e-5, atol=1e-5)

    py, npz = export.to_numpy_module(graph, out, obs_dim, want.shape[1], str(tmp_path / "policy.py"))
    assert os.path.basename(npz) == "policy.npz" and os.path.exists(npz)
    source = open(py).read()
    imports = {line.split()[1] for line in source.splitlines() if line.startswith(("import ", "from "))}
    assert imports == {"os", "numpy"}, imports  # dependency-free: numpy and the standard library only
    policy = _load_module(py).Policy()
    np.testing.assert_allclose(policy(obs), want, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(policy(obs[3]), want[3], rtol=1e-5, atol=1e-5)  # one observation, no batch axis


def test_every_locomotion_recipe_has_an_exporter():
    """Each algorithm a recipe (unilab_jax.recipes, what experiments/*.py run) trains on a walking task has an actor
    builder."""
    import re

    from unilab_jax import recipes

    found = set()
    for name in recipes.names():
        if re.search(r"go1|go2|g1", name) and "mjx" not in name:
            r = recipes.get(name)
            found |= {"hora_teacher", "hora_student"} if r.launcher == "run_hora" else {r.algo}
    assert found and found <= set(export.ACTORS), found - set(export.ACTORS)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "unilab_jax.export", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


def test_bad_format_and_missing_checkpoint_fail_clearly(tmp_path):
    bad = _cli("--logdir", str(tmp_path), "--format", "tflite", "--out", str(tmp_path / "x"))
    assert bad.returncode == 2 and "--format='tflite': choose one of onnx, numpy" in bad.stderr
    (tmp_path / "checkpoints").mkdir()
    empty = _cli("--logdir", str(tmp_path), "--format", "onnx", "--out", str(tmp_path / "x.onnx"))
    assert empty.returncode == 2 and "no checkpoint under" in empty.stderr, empty.stderr
    nothing = _cli("--logdir", str(tmp_path / "nowhere"), "--format", "numpy", "--out", str(tmp_path / "x.py"))
    assert nothing.returncode == 2 and "holds no checkpoints folder" in nothing.stderr, nothing.stderr
    assert not os.path.exists(tmp_path / "x.onnx") and not os.path.exists(tmp_path / "x.py")
