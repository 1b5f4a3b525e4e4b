"""Rollouts on several hosts through Ray (``unilab_jax/runtime/ray_pool.py``): a local two-node cluster trains
cart-pole through a remote worker pool, survives losing the second node mid-run, and every Ray process is gone
after; nothing imports Ray without ``--ray_address``.

The cluster (``ray.cluster_utils.Cluster``: a head and a second node with their own resources, 1 CPU each, no
dashboard, bound to 127.0.0.1, a private temp dir) runs in a subprocess: this file as a script. On Linux Ray
rewrites a loopback address to the machine's outward IP before connecting (``resolve_ip_for_localhost``);
``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` in the subprocess keeps every connection on 127.0.0.1.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# SAC's cart-pole recipe of tests/test_offpolicy_training.py (final return >= 150 there) at twice its utd, with
# 1 worker x 16 envs on each of the two nodes (2 x 16 envs as in that test) and a smaller ring per worker (4 rings
# of 250k transitions: the two hosts' and the learner's copies).
RECIPE = {"actor_hidden": (64, 64), "critic_hidden": (64, 64), "batch_size": 256, "updates_per_call": 32,
          "publish_every": 32, "utd": 0.025, "learning_starts": 5_000, "replay_capacity": 250_000,
          "actor_learning_rate": 1e-3, "critic_learning_rate": 1e-3, "alpha_learning_rate": 1e-3,
          "gamma": 0.98, "tau": 0.02}
STEPS = 450_000
# Measured (2-core VM), at that test's utd 0.0125: seeds 0-5 168-200 under load 15-20 (55-68 s per run), but on an
# idle VM (15 s runs) seed 0 gave 174, 149, 185, 199 and a CI run 112: the learner's data depends on the hosts'
# timing. At utd 0.025 and 450k: seeds 0-5 192-199, seed 0 five more times 189-200, under two busy loops 191-200 (20 s
# per run idle; second node killed at 151-157k env steps). Threshold 150, as the local test.
# Budget 450k -> 350k (later session, evaluations every 50k): seeds 0-2 at 450k evaluated >= 186 from 350k on (the
# lowest from 250k on: 163, seed 2 at 300k); seeds 3, 0, 4 at 350k ended at 200, 192, 199 (20-21 s per run). Back to
# 450k (2026-11-28): a fresh-clone CI run at 350k ended at 123 (the whole suite on the 2 cores); at 450k, two runs at
# once beside a busy loop (56-58 s each): seeds 0 / 1 ended at 187 / 199.
KILL_AT = 150_000  # env steps received when the second node is removed (SIGKILL of its raylet and workers)


def _ray_processes(temp_dir: str) -> list[str]:
    """Command lines of live processes started for the cluster in ``temp_dir``."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if temp_dir in cmd:
            found.append(f"{pid}: {cmd[:200]}")
    return found


def _cluster_run(temp_dir: str, logdir: str, seed: int = 0) -> dict:
    """Starts the cluster, trains with the killer thread, shuts everything down; returns what happened."""
    import threading
    import time

    import ray
    from ray.cluster_utils import Cluster

    from unilab_jax import algos
    from unilab_jax.config import apply_overrides
    from unilab_jax.training.trainer import RunConfig, Trainer

    t0 = time.time()
    node = {"num_cpus": 1, "node_ip_address": "127.0.0.1", "temp_dir": temp_dir, "include_dashboard": False,
            "object_store_memory": 100 * 1024 * 1024}
    cluster = Cluster(initialize_head=True, head_node_args=node)
    try:
        second = cluster.add_node(**{**node, "resources": {"second_host": 1}})
        cluster.wait_for_nodes()
        up_s = time.time() - t0
        module = algos.get("sac")
        run = RunConfig(algo="sac", task="cartpole_balance", num_workers=1, envs_per_worker=16, total_steps=STEPS,
                        seed=seed, logdir=logdir, ray_address=cluster.address, ray_workers_per_host=1)
        trainer = Trainer(run, module, apply_overrides(module.Config(), RECIPE), {})
        killed: dict = {}

        def kill_second_node() -> None:
            metrics = os.path.join(logdir, "metrics.jsonl")
            while not trainer._stop.is_set():
                time.sleep(0.2)
                if not os.path.exists(metrics):
                    continue
                with open(metrics) as f:
                    rows = [json.loads(line) for line in f if line.endswith("\n")]
                steps = [r["step"] for r in rows if r.get("ray/hosts_alive") == 2]
                if steps and steps[-1] >= KILL_AT:
                    killed["at"] = steps[-1]
                    cluster.remove_node(second, allow_graceful=False)
                    return

        killer = threading.Thread(target=kill_second_node, daemon=True)
        killer.start()
        summary = trainer.train()
        killer.join(timeout=5)
        rows = [json.loads(line) for line in open(os.path.join(logdir, "metrics.jsonl"))]
        alive = [(r["step"], r["ray/hosts_alive"]) for r in rows if "ray/hosts_alive" in r]
        return {"summary": summary, "killed_at": killed.get("at"), "alive": alive, "up_s": up_s,
                "overrun": max(r["ray/rows_overrun"] for r in rows if "ray/rows_overrun" in r),
                "wall_s": time.time() - t0}
    finally:
        ray.shutdown()
        cluster.shutdown()


def _store_only_pool(envs: int = 2):
    """A RayPool with its learner-side rings and bookkeeping but no Ray: ``_store`` as the pump calls it."""
    import numpy as np

    from unilab_jax.runtime.buffers import ReplayBuffer
    from unilab_jax.runtime.ray_pool import RayPool

    pool = object.__new__(RayPool)
    pool.envs_per_worker, pool.hosts, pool.offsets = envs, ["a", "b"], np.array([0, 1, 3])
    pool.buffer = ReplayBuffer.create({"obs": ((1,), np.float32)}, 3, envs, 64)
    pool._seq, pool._next = [0, 0], np.zeros(3, np.int64)
    pool._received, pool._host_stats, pool.overrun = np.zeros(2, np.int64), [None, None], 0
    return pool


def _reply(seq, start, n):
    import numpy as np

    rows = np.concatenate([np.arange(s, s + k, dtype=np.float32) for s, k in zip(start, n)])[:, None]
    return {"seq": seq, "start": np.array(start), "n": np.array(n), "rows": {"obs": rows}, "stats": {}}


def test_pulled_rows_land_once_in_order_and_repeats_are_refused():
    import numpy as np

    pool = _store_only_pool()
    try:
        pool._store(1, _reply(1, [0, 0], [4, 2]))  # host b: its workers are rings 1 and 2
        pool._store(1, _reply(2, [4, 2], [2, 0]))
        pool._store(0, _reply(1, [6], [2]))  # host a skipped rows 0-5 (its ring overran): counted, not invented
        assert pool.buffer.count(1) == 6 and pool.buffer.count(2) == 2 and pool.buffer.count(0) == 2
        np.testing.assert_array_equal(pool.buffer._data[1]["obs"][:6, 0], np.arange(6))
        np.testing.assert_array_equal(pool.buffer._data[0]["obs"][:2, 0], [6, 7])
        assert pool.overrun == 6 and pool._received.tolist() == [2, 8]
        with pytest.raises(RuntimeError, match="pull 2 after pull 2"):
            pool._store(1, _reply(2, [6, 2], [2, 0]))  # the same pull again
        with pytest.raises(RuntimeError, match="rows from 4"):
            pool._store(1, _reply(3, [4, 2], [2, 0]))  # rows already received
    finally:
        pool.buffer.close()


def test_nothing_imports_ray_without_ray_address():
    code = ("import sys; import unilab_jax.training.trainer, unilab_jax.apps.cli, unilab_jax.runtime.pool, "
            "unilab_jax.runtime.ray_pool, unilab_jax.runtime.host_rollouts, unilab_jax.training.sharding; "
            "from unilab_jax.training.trainer import RunConfig; RunConfig('sac', 'cartpole_balance'); "
            "print(sorted(m for m in sys.modules if m == 'ray' or m.startswith('ray.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "[]"


@pytest.mark.parametrize("algo,flags,message", [
    ("sac", ["--ray_address=head-without-port"], "give 'auto' or HOST:PORT"),
    ("sac", ["--ray_address=10.0.0.1:99999"], "give 'auto' or HOST:PORT"),
    ("ppo", ["--ray_address=auto"], "off-policy algorithms only"),
    ("sac", ["--ray_address=auto", "--serial"], "cannot be combined with --serial"),
    ("sac", ["--ray_workers_per_host=4"], "needs --ray_address"),
    ("sac", ["--devices=0"], "give 'all' or a positive number"),
    ("sac", ["--devices=64"], r"local cpu device\(s\) exist"),
    ("sac", ["--devices=2", "--platform=mlx"], "data-parallel learners are JAX's"),
    ("mjx", ["--devices=2"], "MJX runs train on one device"),
    ("mjx", ["--ray_address=auto"], "flag of the CPU-worker runtime"),
])
def test_scale_out_flags_fail_before_anything_starts(tmp_path, algo, flags, message):
    from absl.testing import flagsaver

    from unilab_jax.apps import cli, mjx_cli

    with flagsaver.flagsaver():
        cli.FLAGS(["prog", *flags, f"--logdir={tmp_path / 'x'}"])
        with pytest.raises(cli.FlagError, match=message):
            if algo == "mjx":
                mjx_cli.build_run("ppo", "go1_joystick_flat", {}, {}, 1000, 64, 1)
            else:
                cli.build_run(algo, "cartpole_balance", {}, {}, 1000)


def test_two_node_cluster_trains_cartpole_and_survives_a_lost_node(tmp_path):
    pytest.importorskip("ray")
    temp_dir = tempfile.mkdtemp(prefix="uray", dir="/tmp")  # short: Ray's unix socket paths must fit 107 bytes
    # Ray writes the cluster's address to $RAY_TMPDIR/ray/ray_current_cluster whatever the temp dir (and fails if that
    # folder is missing): point it at the private folder too, so nothing lands in /tmp/ray.
    os.makedirs(os.path.join(temp_dir, "ray"))
    env = dict(os.environ, RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0", RAY_USAGE_STATS_ENABLED="0", RAY_TMPDIR=temp_dir,
               PYTHONPATH=os.pathsep.join(p for p in (ROOT, os.environ.get("PYTHONPATH", "")) if p))
    try:
        out = subprocess.run([sys.executable, os.path.abspath(__file__), os.path.join(temp_dir, "ray"),
                              str(tmp_path / "run")], env=env,
                             capture_output=True, text=True, timeout=600, cwd=ROOT)
        assert out.returncode == 0, out.stderr[-5000:]
        result = json.loads(out.stdout.strip().splitlines()[-1])
        leftover = _ray_processes(temp_dir)
    finally:
        import shutil

        shutil.rmtree(temp_dir, ignore_errors=True)
    assert not leftover, leftover
    summary = result["summary"]
    assert summary["env_steps"] >= STEPS and not summary["interrupted"], result
    assert result["killed_at"] is not None and result["killed_at"] < STEPS, result
    hosts = [n for _, n in result["alive"]]
    assert hosts[0] == 2 and hosts[-1] == 1, result["alive"]  # both hosts fed the learner, then one went on alone
    assert result["overrun"] == 0, result
    assert summary["eval/return"] >= 150.0, result


if __name__ == "__main__":
    print(json.dumps(_cluster_run(sys.argv[1], sys.argv[2], *map(int, sys.argv[3:])), default=float))
