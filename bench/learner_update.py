"""One learner update, JAX vs MLX on the same machine, same batch: prints a table, writes JSON.

    python bench/learner_update.py --algos ppo fastsac --repeats 5 --out bench/results/learner_update_local.json

PPO: one full update (GAE targets + epochs x minibatches) on a Go1-sized trajectory batch
([T=24, B] with Go1's observation sizes). Off-policy algorithms: one ``update`` call (``updates_per_call``
gradient steps on [U, batch_size] samples). The first call (compilation) is reported separately;
steady state is the median of ``--repeats`` calls, each waited on (``block_until_ready`` / ``mx.eval``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO not in sys.path:
    sys.path.insert(0, REPO)

from tasks.base import TaskSpec  # noqa: E402
from unilab_jax import algos  # noqa: E402
from unilab_jax.config import apply_overrides  # noqa: E402

# Go1 joystick sizes (actor 48, privileged critic 123, 12 actions).
SPEC = TaskSpec(name="go1_sizes", obs_dim=48, critic_obs_dim=123, action_dim=12, episode_length=1000, ctrl_dt=0.02,
                reward_terms=("r",))


def _trajectory_batch(rng: np.random.Generator, t: int, b: int) -> dict[str, np.ndarray]:
    s, a = SPEC, SPEC.action_dim
    f = np.float32
    return {"obs": rng.normal(size=(t, b, s.obs_dim)).astype(f),
            "critic_obs": rng.normal(size=(t, b, s.critic_obs_dim)).astype(f),
            "next_critic_obs": rng.normal(size=(t, b, s.critic_obs_dim)).astype(f),
            "action": rng.normal(size=(t, b, a)).astype(f), "reward": (rng.random((t, b)) * 0.02).astype(f),
            "terminated": rng.random((t, b)) < 0.01, "truncated": rng.random((t, b)) < 0.001,
            "log_prob": rng.normal(size=(t, b)).astype(f), "mean": rng.normal(size=(t, b, a)).astype(f),
            "log_std": np.full((t, b, a), -1.0, f)}


def _replay_batch(rng: np.random.Generator, u: int, b: int) -> dict[str, np.ndarray]:
    s, a = SPEC, SPEC.action_dim
    f = np.float32
    return {"obs": rng.normal(size=(u, b, s.obs_dim)).astype(f),
            "critic_obs": rng.normal(size=(u, b, s.critic_obs_dim)).astype(f),
            "action": np.tanh(rng.normal(size=(u, b, a))).astype(f), "reward": (rng.random((u, b)) * 0.02).astype(f),
            "next_obs": rng.normal(size=(u, b, s.obs_dim)).astype(f),
            "next_critic_obs": rng.normal(size=(u, b, s.critic_obs_dim)).astype(f),
            "terminated": rng.random((u, b)) < 0.01, "truncated": rng.random((u, b)) < 0.001}


def _sync(platform_name: str, tree) -> None:
    if platform_name == "jax":
        import jax

        jax.block_until_ready(tree)
    else:
        import mlx.core as mx
        from mlx.utils import tree_flatten

        mx.eval([v for _, v in tree_flatten(tree)])


def measure(algo: str, platform_name: str, batch_np: dict, repeats: int, config,
            profile_dir: str = "") -> dict[str, float]:
    from unilab_jax import xp as shim

    xp = shim.get(platform_name)
    learner = algos.get(algo).make_learner(platform_name, config, SPEC)
    state = learner.init(xp.random.key(0))
    batch = {k: xp.from_numpy(v) for k, v in batch_np.items()}
    t0 = time.perf_counter()
    state, metrics = learner.update(state, batch)
    _sync(platform_name, (state, metrics))
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        state, metrics = learner.update(state, batch)
        _sync(platform_name, (state, metrics))
        times.append(time.perf_counter() - t0)
    if profile_dir and platform_name == "jax":
        import jax

        with jax.profiler.trace(os.path.join(profile_dir, algo), create_perfetto_trace=True):
            for _ in range(3):
                state, metrics = learner.update(state, batch)
            _sync(platform_name, (state, metrics))
    return {"first_call_s": first, "steady_s": float(np.median(times)), "repeats": repeats}


def _recipe(path: str) -> dict:
    """The ``RECIPE`` dict of an experiment script, read without running it."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("_bench_recipe", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return dict(module.RECIPE)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algos", nargs="+", default=["ppo"])
    ap.add_argument("--platforms", nargs="+", default=["jax", "mlx"])
    ap.add_argument("--ppo_envs", type=int, default=1024, help="B of the PPO batch [24, B]")
    ap.add_argument("--offpolicy_batch", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--recipe", help="experiment script (e.g. experiments/fastsac_go1.py) whose RECIPE overrides the "
                    "defaults of the algorithms named by --algos (its batch_size wins over --offpolicy_batch)")
    ap.add_argument("--profile_dir", default="", help="JAX: also trace 3 steady calls per algorithm with "
                    "jax.profiler into DIR/<algo> (TensorBoard/XProf trace plus a Perfetto JSON)")
    ap.add_argument("--out", default=os.path.join(REPO, "bench", "results", "learner_update_local.json"))
    args = ap.parse_args()
    recipe = _recipe(args.recipe) if args.recipe else {}
    rng = np.random.default_rng(0)
    rows = []
    for algo in args.algos:
        module = algos.get(algo)
        if module.BUFFER == "trajectory":
            config = apply_overrides(module.Config(), recipe)
            batch = _trajectory_batch(rng, config.horizon, args.ppo_envs)
            shape = f"[{config.horizon}, {args.ppo_envs}], {config.num_epochs}x{config.num_minibatches} minibatches"
        else:
            config = apply_overrides(module.Config(), {"batch_size": args.offpolicy_batch, **recipe})
            batch = _replay_batch(rng, config.updates_per_call, config.batch_size)
            shape = f"[{config.updates_per_call}, {config.batch_size}] ({config.updates_per_call} gradient steps)"
        for plat in args.platforms:
            result = measure(algo, plat, batch, args.repeats, config, args.profile_dir)
            rows.append({"algo": algo, "platform": plat, "batch": shape, **result})
            print(f"{algo:9s} {plat:4s} {shape:48s} first {result['first_call_s']:7.2f} s  "
                  f"steady {result['steady_s'] * 1e3:9.1f} ms", flush=True)
    import jax

    machine = {"hostname": platform.node(), "date": datetime.datetime.now(datetime.timezone.utc).isoformat(),
               "cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
               "python": platform.python_version(), "jax": jax.__version__, "jax_devices": str(jax.devices()),
               "recipe": args.recipe, "xla_flags": os.environ.get("XLA_FLAGS", "")}
    if "mlx" in args.platforms:
        import mlx.core as mx

        machine.update({"mlx": mx.__version__, "mlx_device": str(mx.default_device())})
    with open(args.out, "w") as f:
        json.dump({"machine": machine, "rows": rows}, f, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
