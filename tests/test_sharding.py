"""Data-parallel learners (``unilab_jax/training/sharding.py``): on 2 emulated CPU devices the sharded update equals the
single-device one (same state, batches and key) within float tolerance, and every device holds the same copy of the
state, for FastSAC and PPO (TD3, SAC and FlashSAC share FastSAC's wrapper; TD3 measured 6e-8); the sharded
device replay mirror draws the same rows as the single-device one; bad ``--devices`` values are refused.

The device count of the CPU backend is fixed when jax starts (``XLA_FLAGS=--xla_force_host_platform_device_count``),
so the comparison runs in a fresh interpreter (this file as a script), whatever the pytest worker imported before.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from compile_options import FAST_COMPILE_FLAGS

K = 3  # learner calls compared
# Measured (2-core VM): max |diff| over every leaf after 3 calls, FastSAC 1.1e-6, TD3 6e-8, PPO 3e-8, metrics
# <= 1e-6; compiled with FAST_COMPILE_FLAGS (as the script is run here), FastSAC 3.4e-6.
ATOL = 1e-4


def _batches(rng: np.random.Generator, shape: tuple[int, int], obs_dim: int, act_dim: int, extra: dict) -> list:
    out = []
    for _ in range(K):
        obs = rng.normal(size=(*shape, obs_dim)).astype(np.float32)
        b = {"obs": obs, "critic_obs": obs, "action": rng.uniform(-1, 1, (*shape, act_dim)).astype(np.float32),
             "reward": rng.normal(size=shape).astype(np.float32),
             "next_obs": rng.normal(size=(*shape, obs_dim)).astype(np.float32),
             "terminated": rng.random(shape) < 0.05, "truncated": rng.random(shape) < 0.02}
        b["next_critic_obs"] = b["next_obs"]
        b.update({k: f(shape) for k, f in extra.items()})
        out.append(b)
    return out


def _compare(name: str, split: str = "batch") -> dict:
    """Runs K updates on one device and on two (the batch or the critics split); returns the largest absolute
    differences."""
    import jax

    from tasks.base import TaskSpec
    from unilab_jax import algos
    from unilab_jax.config import apply_overrides
    from unilab_jax.training import sharding

    assert jax.device_count() == 2, jax.devices()
    spec = TaskSpec("check", 6, 6, 2, 50, 0.02, ())
    rng = np.random.default_rng(0)
    module = algos.get(name)
    if name == "ppo":
        config = apply_overrides(module.Config(), {"actor_hidden": (32, 32), "critic_hidden": (32, 32),
                                                   "num_minibatches": 2, "num_epochs": 2})
        extra = {"log_prob": lambda s: rng.normal(size=s).astype(np.float32) - 2.0,
                 "mean": lambda s: rng.normal(size=(*s, 2)).astype(np.float32) * 0.1,
                 "log_std": lambda s: np.full((*s, 2), -0.5, np.float32),
                 "policy_version": lambda s: np.zeros(s, np.int32)}
        batches = _batches(rng, (8, 16), 6, 2, extra)
    else:
        config = apply_overrides(module.Config(), {"actor_hidden": (32, 32), "critic_hidden": (32, 32),
                                                   "batch_size": 64, "updates_per_call": 2})
        batches = _batches(rng, (2, 64), 6, 2, {})
    single = algos.make_learner(module, "jax", config, spec)
    learner = algos.make_learner(module, "jax", config, spec)
    if name != "ppo":  # "auto" LayerNorm kernels as one NVIDIA GPU resolves them; on two devices, XLA's programs
        learner.ln_kernels = ("pallas", "pallas")
    sharded = sharding.make(learner, 2, split)
    assert isinstance(sharded, sharding.DataParallel) and sharded.num_devices == 2
    assert getattr(learner, "ln_kernels", ("xla", "xla")) == ("xla", "xla")
    s1, s2 = single.init(jax.random.key(0)), sharded.init(jax.random.key(0))
    for b in batches:
        s1, m1 = single.update(s1, {k: jax.numpy.asarray(v) for k, v in b.items()})
        s2, m2 = sharded.update(s2, {k: sharded.from_numpy(v) for k, v in b.items()})
    leaves2 = jax.tree_util.tree_leaves(s2)
    assert all(len(x.sharding.device_set) == 2 for x in leaves2 if hasattr(x, "sharding"))
    # Batch split: every leaf replicated. Critics split: each device holds one of the two critics (every leaf of
    # the critics, their targets and optimizer moments), the rest replicated.
    split_leaves = [x for x in leaves2 if hasattr(x, "sharding") and not x.sharding.is_fully_replicated]
    assert all(x.addressable_shards[0].data.shape[0] == x.shape[0] // 2 for x in split_leaves)
    critic_leaves = sum(len(jax.tree_util.tree_leaves(getattr(s2, f))) for f in sharding.CRITIC_FIELDS
                        if hasattr(s2, f))
    n_split = len(split_leaves)
    leaves2 = [x for x in leaves2 if not hasattr(x, "sharding") or x.sharding.is_fully_replicated]

    def diff(a, b):
        a, b = np.asarray(jax.random.key_data(a) if jax.numpy.issubdtype(a.dtype, jax.dtypes.prng_key) else a), \
            np.asarray(jax.random.key_data(b) if jax.numpy.issubdtype(b.dtype, jax.dtypes.prng_key) else b)
        return float(np.max(np.abs(a.astype(np.float64) - b.astype(np.float64)))) if a.size else 0.0

    state = max(diff(a, b) for a, b in zip(jax.tree_util.tree_leaves(s1), jax.tree_util.tree_leaves(s2)))
    before = jax.tree_util.tree_leaves(single.init(jax.random.key(0)))
    moved = max(diff(a, b) for a, b in zip(before, jax.tree_util.tree_leaves(s1))
                if jax.numpy.issubdtype(a.dtype, jax.numpy.floating))
    metrics = max(diff(m1[k], m2[k]) for k in m1)
    # Each device's copy of the replicated state
    replicas = max(diff(x.addressable_shards[0].data, x.addressable_shards[1].data) for x in leaves2
                   if hasattr(x, "addressable_shards"))
    return {"state": state, "metrics": metrics, "moved": moved, "replicas": replicas, "split_leaves": n_split,
            "critic_leaves": critic_leaves}


def _dtype() -> dict:
    """Whether the data-parallel FastSAC program multiplies in bf16 where the learner's compute_dtype says so (it
    once compiled the learner's ``_update`` outside ``xp.compute_dtype``: float32 on two GPUs, bf16 on one)."""
    import jax

    from tasks.base import TaskSpec
    from unilab_jax import algos
    from unilab_jax.config import apply_overrides
    from unilab_jax.training import sharding

    spec = TaskSpec("check", 6, 6, 2, 50, 0.02, ())
    module = algos.get("fastsac")
    batch = _batches(np.random.default_rng(0), (2, 64), 6, 2, {})[0]
    out = {}
    for dtype in ("float32", "bfloat16"):
        config = apply_overrides(module.Config(), {"actor_hidden": (32, 32), "critic_hidden": (32, 32),
                                                   "batch_size": 64, "updates_per_call": 2, "compute_dtype": dtype})
        sharded = sharding.make(algos.make_learner(module, "jax", config, spec), 2)
        state = sharded.init(jax.random.key(0))
        text = sharded._update.lower(state, {k: sharded.from_numpy(v) for k, v in batch.items()}).as_text()
        out[dtype] = "bf16" in text
    return out


def _mirror() -> dict:
    """The replay mirror on two devices: same rows as on one, gathered batch split along B."""
    import jax

    from unilab_jax.runtime.buffers import ReplayBuffer
    from unilab_jax.training import sharding
    from unilab_jax.training.device_replay import DeviceReplay

    ring = ReplayBuffer.create({"obs": ((3,), np.float32), "reward": ((), np.float32)}, 2, 4, 64)
    try:
        for w in range(2):
            for step in range(5):
                _, views = ring.rows(w)
                views["obs"][:] = np.arange(4)[:, None] + 100 * w + 10 * step
                views["reward"][:] = w
                ring.commit(w)
        one = DeviceReplay(ring, ("obs", "reward"))
        dp = sharding.DataParallel(object.__new__(_Stub), jax.local_devices()[:2])
        two = DeviceReplay(ring, ("obs", "reward"), dp)
        one.sync(), two.sync()
        g1, g2 = one.sample((2, 8), np.random.default_rng(1)), two.sample((2, 8), np.random.default_rng(1))
        return {"same": bool(all(np.array_equal(np.asarray(g1[k]), np.asarray(g2[k])) for k in g1)),
                "split": [len(g2["obs"].sharding.device_set), g2["obs"].sharding.spec[1]],
                "data_devices": len(two.data["obs"].sharding.device_set)}
    finally:
        ring.close()


def _train(tmp: str) -> dict:
    """Short serial runs of the Trainer with --devices=2: FastSAC through the sharded replay mirror, PPO."""
    import logging

    import jax

    from unilab_jax import algos
    from unilab_jax.config import apply_overrides
    from unilab_jax.training import sharding
    from unilab_jax.training.trainer import RunConfig, Trainer

    compiled_by = []  # the threads that compiled an update (XLA's compile log)

    class _Compiles(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if "XLA compilation of jit(traced_update)" in record.getMessage():
                compiled_by.append(record.threadName)

    logging.getLogger().addHandler(_Compiles(logging.WARNING))
    jax.config.update("jax_log_compiles", True)
    out = {}
    for algo, recipe, extra in [
        ("fastsac", {"actor_hidden": (32, 32), "critic_hidden": (32, 32), "batch_size": 64, "updates_per_call": 2,
                     "learning_starts": 256, "utd": 0.5, "num_atoms": 11}, {"replay_on_device": "on",
                                                                            "precompile": "on"}),
        ("fastsac_critics", {"actor_hidden": (32, 32), "critic_hidden": (32, 32), "batch_size": 64,
                             "updates_per_call": 2, "learning_starts": 256, "utd": 0.5, "num_atoms": 11},
         {"replay_on_device": "on", "device_split": "critics", "precompile": "on"}),
        ("ppo", {"actor_hidden": (32, 32), "critic_hidden": (32, 32), "horizon": 8, "num_minibatches": 2}, {}),
    ]:
        module = algos.get(algo.split("_")[0])
        run = RunConfig(algo=module.__name__.rsplit(".", 1)[-1], task="cartpole_balance", num_workers=2,
                        envs_per_worker=8, total_steps=1_024, logdir=os.path.join(tmp, algo), serial=True, eval_envs=2,
                        devices="2", **extra)
        trainer = Trainer(run, module, apply_overrides(module.Config(), recipe), {})
        assert isinstance(trainer.learner, sharding.DataParallel)
        compiled_by.clear()
        summary = trainer.train()
        out[algo] = {"updates": summary["updates"], "return": summary["eval/return"], "compiled_by": list(compiled_by)}
    # Resume of the sharded PPO run: the checkpoint's state is replicated again and training goes on.
    resumed = Trainer(dataclasses.replace(run, total_steps=2_048, resume=True), module,
                      apply_overrides(module.Config(), recipe), {}).train()
    out["ppo_resumed_updates"] = resumed["updates"]
    return out


class _Stub:
    """Enough of a learner for :class:`DataParallel` (the mirror needs its mesh only)."""

    config = spec = None

    @staticmethod
    def traced_update(state, batch):
        return state, {}


def _run_script(*args: str, tmp: str = "") -> dict:
    # The script runs from tests/, whose tests/tasks folder would shadow the top-level ``tasks`` package
    # for an editable install (a fresh clone): the repository root goes first on the path. Its programs compile
    # fast (tests/compile_options.py: 34 -> 12 CPU seconds).
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count=2 {FAST_COMPILE_FLAGS}",
               JAX_PLATFORMS="cpu", SHARDING_TMP=tmp,
               PYTHONPATH=os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p))
    out = subprocess.run([sys.executable, os.path.abspath(__file__), *args], env=env, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-4000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_sharded_updates_equal_single_device(tmp_path):
    result = _run_script("fastsac", "ppo", "fastsac:critics", "td3:critics", "mirror", "dtype", "train",
                         tmp=str(tmp_path))
    for name in ("fastsac", "ppo", "fastsac:critics", "td3:critics"):
        r = result[name]
        assert r["moved"] > 1e-3, r  # the updates changed the state, so equality is not trivial
        assert r["state"] <= ATOL and r["metrics"] <= ATOL, (name, r)
        assert r["replicas"] == 0.0, (name, r)  # the devices' copies of the replicated leaves are the same, bit for bit
        # Batch split: nothing split; critics split: exactly the critic fields' ensemble leaves (not their counts)
        assert r["split_leaves"] == 0 if name in ("fastsac", "ppo") else 0 < r["split_leaves"] < r["critic_leaves"], r
    assert result["mirror"] == {"same": True, "split": [2, "batch"], "data_devices": 2}
    assert result["dtype"] == {"float32": False, "bfloat16": True}  # the sharded program keeps the learner's dtype
    # The Trainer with --devices=2 (serial workers, tiny budgets): it updates and evaluates.
    assert result["train"]["fastsac"]["updates"] > 0 and result["train"]["ppo"]["updates"] == 1_024 // 128
    assert result["train"]["fastsac_critics"]["updates"] > 0  # --device_split=critics through the replicated mirror
    # --precompile=on: each split program compiled once, ahead, in the precompile thread (the first update waits for it)
    assert result["train"]["fastsac"]["compiled_by"] == ["precompile"], result["train"]
    assert result["train"]["fastsac_critics"]["compiled_by"] == ["precompile"], result["train"]
    assert all(r["return"] > 0 for k, r in result["train"].items() if k != "ppo_resumed_updates"), result["train"]
    assert result["train"]["ppo_resumed_updates"] == 2_048 // 128


def test_pallas_layer_norm_kernels_are_refused_on_several_devices():
    """A Pallas call is one device's program: the LayerNorm kernels are refused with a message on two devices and
    kept on one."""
    from unilab_jax import algos
    from unilab_jax.training import sharding

    config = algos.get("fastsac").Config(ln_forward="pallas")
    with pytest.raises(ValueError, match="ln_forward=pallas run on one device only"):
        sharding.check_kernels(config, 2)
    sharding.check_kernels(config, 1)
    sharding.check_kernels(algos.get("fastsac").Config(), 2)


def test_devices_flag_values_are_checked():
    sharding = pytest.importorskip("unilab_jax.training.sharding")
    assert sharding.parse_devices("all") is None and sharding.parse_devices("2") == 2
    for bad in ("0", "-1", "two"):
        with pytest.raises(ValueError, match="--devices"):
            sharding.parse_devices(bad)
    n = len(sharding.jax.local_devices())
    with pytest.raises(ValueError, match=f"only {n} local"):
        sharding.local_devices(n + 1)
    with pytest.raises(ValueError, match="divisible"):
        sharding.check_batch(2, 255, "batch_size")


if __name__ == "__main__":
    results = {}
    for what in sys.argv[1:]:
        results[what] = {"mirror": _mirror, "dtype": _dtype, "train": lambda: _train(os.environ["SHARDING_TMP"])}.get(
            what, lambda what=what: _compare(*what.split(":")))()
    print(json.dumps(results))
