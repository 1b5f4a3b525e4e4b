"""One learner update, JAX vs MLX on the same machine, same batch, float32 vs bf16 matmuls: prints a table,
writes JSON.

    python bench/learner_update.py --algos ppo fastsac --repeats 5 --out bench/results/learner_update_local.json
    python bench/learner_update.py --algos fastsac --recipe experiments/fastsac_go1.py --platforms jax \
        --dtypes float32 bfloat16 --out fastsac_go1.json          # on the GPU
    python bench/learner_update.py --algos rlpd --recipe experiments/rlpd_franka_peg.py --images 64x64x12 \
        --sizes franka --platforms jax --dtypes float32 bfloat16 --config updates_per_call=64 \
        --config actor_every=2 --out rlpd_peg_images.json       # image RLPD's update, on the GPU

PPO: one full update (GAE targets + epochs x minibatches) on a trajectory batch ([T=24, B] with the task's
observation sizes, ``--sizes``). Off-policy algorithms: one ``update`` call (``updates_per_call`` gradient
steps on [U, batch_size] samples). The first call (compilation) is reported separately; steady state is
the median of ``--repeats`` calls, each waited on (``block_until_ready`` / ``mx.eval``).

Per row: gradient steps/s (off-policy: U per call; PPO: epochs x minibatches per update) and the achieved
matmul TFLOP/s: the FLOPs of every ``dot_general`` in the traced float32 update (2 x output elements x
contracted size; scans counted ``length`` times, the larger ``cond`` branch -- TD3's delayed actor step --
counted every step; the bf16 program multiplies the same shapes), divided by the steady time. Elementwise
work is not counted, so this is the rate of the useful matrix work, comparable across dtypes. Convolutions
(the image encoder's, forward and backward) are counted the same way apart from the matmuls (2 x output
elements x input features x kernel window: ``conv_gflop_per_call``, ``conv_tflops_per_s``; an input gradient
is a convolution over the zero-padded cotangent and counts the padding: 31^2 / 29^2 of the true work on the
second 64 px layer).

``--images HxWxC``: the off-policy update on a task with uint8 images of that shape (``image`` and ``next_image``
in the batch, random pixels; SAC, RLPD, SAC Flow): the image learner of ``algos/offpolicy/image_obs.py`` with the
config's encoder (the defaults are DrQ's, which the Franka image jobs run: ``bench/franka_gpu_runs.sh``).
``--sizes franka``: those jobs' observation sizes (12 robots).

``--dtypes``: the JAX learners' ``compute_dtype`` (off-policy: the config field; PPO, which has no such
option, is traced inside ``xp.compute_dtype`` to show what it would give).
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
from unilab_jax.config import apply_overrides, parse_overrides  # noqa: E402

# Observation sizes (actor, privileged critic, actions) of the locomotion tasks, as their TaskSpecs give them.
SIZES = {"go1": (48, 123, 12), "go2": (49, 52, 12), "g1": (58, 66, 15),
         # The Franka image jobs (tasks/robot.py): proprioception 13 + 2 arm kinds + 12 robot ids; the critic + 1.
         "franka": (27, 28, 7)}
SPEC = TaskSpec(name="go1_sizes", obs_dim=48, critic_obs_dim=123, action_dim=12, episode_length=1000, ctrl_dt=0.02,
                reward_terms=("r",))


def _spec(sizes: str, image_shape: tuple[int, ...] = ()) -> TaskSpec:
    obs, critic, act = SIZES[sizes]
    return TaskSpec(name=f"{sizes}_sizes", obs_dim=obs, critic_obs_dim=critic, action_dim=act, episode_length=1000,
                    ctrl_dt=0.02, reward_terms=("r",), image_shape=image_shape)


def _image_shape(text: str) -> tuple[int, int, int]:
    """``"64x64x12"`` -> ``(64, 64, 12)``."""
    parts = text.lower().split("x")
    if len(parts) != 3 or not all(p.isdigit() and int(p) > 0 for p in parts):
        raise argparse.ArgumentTypeError(f"--images must be HxWxC with positive integers (e.g. 64x64x12), got {text!r}")
    return tuple(int(p) for p in parts)


def _trajectory_batch(rng: np.random.Generator, t: int, b: int, s: TaskSpec = SPEC) -> dict[str, np.ndarray]:
    a = s.action_dim
    f = np.float32
    return {"obs": rng.normal(size=(t, b, s.obs_dim)).astype(f),
            "critic_obs": rng.normal(size=(t, b, s.critic_obs_dim)).astype(f),
            "next_critic_obs": rng.normal(size=(t, b, s.critic_obs_dim)).astype(f),
            "action": rng.normal(size=(t, b, a)).astype(f), "reward": (rng.random((t, b)) * 0.02).astype(f),
            "terminated": rng.random((t, b)) < 0.01, "truncated": rng.random((t, b)) < 0.001,
            "log_prob": rng.normal(size=(t, b)).astype(f), "mean": rng.normal(size=(t, b, a)).astype(f),
            "log_std": np.full((t, b, a), -1.0, f)}


def _replay_batch(rng: np.random.Generator, u: int, b: int, s: TaskSpec = SPEC) -> dict[str, np.ndarray]:
    """A replay batch ``[u, b, ...]`` of random transitions, with random uint8 images where ``s`` has them."""
    a = s.action_dim
    f = np.float32
    images = ({k: rng.integers(0, 256, (u, b, *s.image_shape), dtype=np.uint8) for k in ("image", "next_image")}
              if s.image_shape else {})
    return {**images, "obs": rng.normal(size=(u, b, s.obs_dim)).astype(f),
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


def _subjaxprs(value):
    """The jaxprs held by an equation parameter (a jaxpr, a closed jaxpr, or tuples/lists of them; recognised by
    their attributes, which are stable across jax versions, unlike the classes' import paths)."""
    if hasattr(value, "eqns"):
        yield value
    elif hasattr(getattr(value, "jaxpr", None), "eqns"):
        yield value.jaxpr
    elif isinstance(value, tuple | list):
        for v in value:
            yield from _subjaxprs(v)


def jaxpr_flops(jaxpr) -> np.ndarray:
    """FLOPs ``[matmul, conv]`` of the ``dot_general`` and ``conv_general_dilated`` equations of ``jaxpr``:
    2 x output elements x contracted size (a convolution's: the kernel's input features x window); a scan's
    body counts ``length`` times, a ``cond`` its most expensive branch, other sub-jaxprs (pjit, custom
    derivatives, remat) once."""
    total = np.zeros(2)
    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        out = float(np.prod(eqn.outvars[0].aval.shape)) if eqn.outvars else 0.0
        if name == "dot_general":
            (lhs_contract, _), _ = eqn.params["dimension_numbers"]
            lhs = eqn.invars[0].aval.shape
            total[0] += 2.0 * out * float(np.prod([lhs[d] for d in lhs_contract]))
            continue
        if name == "conv_general_dilated":
            rhs_spec = eqn.params["dimension_numbers"].rhs_spec  # (out features, in features, *window)
            rhs = eqn.invars[1].aval.shape
            total[1] += 2.0 * out * float(np.prod([rhs[d] for d in rhs_spec[1:]]))
            continue
        subs = [jaxpr_flops(j) for v in eqn.params.values() for j in _subjaxprs(v)]
        if not subs:
            continue
        if name == "cond":
            total += max(subs, key=lambda f: f.sum())
        elif name == "scan":
            total += eqn.params["length"] * sum(subs)
        else:
            total += sum(subs)
    return total


def update_flops(fn, *args) -> np.ndarray:
    """``[matmul, conv]`` FLOPs of one call ``fn(*args)`` (traced, not run)."""
    import jax

    return jaxpr_flops(jax.make_jaxpr(fn)(*args).jaxpr)


def measure(algo: str, platform_name: str, batch_np: dict, repeats: int, config, profile_dir: str = "",
            spec: TaskSpec = SPEC, dtype: str = "float32") -> dict[str, float]:
    """First-call and steady seconds of ``learner.update`` and, on JAX, its matmul and conv FLOPs. ``dtype`` is the
    compute dtype: off-policy configs carry it; PPO's update is traced inside ``xp.compute_dtype``."""
    import contextlib
    import dataclasses

    from unilab_jax import xp as shim

    xp = shim.get(platform_name)
    if hasattr(config, "compute_dtype"):
        config = dataclasses.replace(config, compute_dtype=dtype)
        scope = contextlib.nullcontext()
    elif dtype != "float32" and platform_name == "jax":
        scope = xp.compute_dtype(dtype)
    elif dtype != "float32":
        raise ValueError(f"{algo} on {platform_name} has no {dtype} path")
    else:
        scope = contextlib.nullcontext()
    learner = algos.get(algo).make_learner(platform_name, config, spec)
    state = learner.init(xp.random.key(0))
    batch = {k: xp.from_numpy(v) for k, v in batch_np.items()}
    # The float32 program's matmul and conv FLOPs (the bf16 one multiplies the same shapes).
    flops = update_flops(learner._update, state, batch) if platform_name == "jax" else None
    with scope:  # the first call traces the update
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

        with jax.profiler.trace(os.path.join(profile_dir, f"{algo}_{dtype}"), create_perfetto_trace=True):
            for _ in range(3):
                state, metrics = learner.update(state, batch)
            _sync(platform_name, (state, metrics))
    steady = float(np.median(times))
    matmul, conv = flops if flops is not None else (None, None)
    per_call = {"matmul": matmul, "conv": conv}
    return {"first_call_s": first, "steady_s": steady, "repeats": repeats,
            **{f"{k}_gflop_per_call": v / 1e9 if v is not None else None for k, v in per_call.items()},
            **{f"{k}_tflops_per_s": v / steady / 1e12 if v is not None else None for k, v in per_call.items()}}


def _recipe(path: str) -> dict:
    """The algorithm recipe an experiment script runs (``unilab_jax.recipes``, by the script's name)."""
    from unilab_jax import recipes

    return recipes.get(os.path.basename(path)).recipe


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algos", nargs="+", default=["ppo"])
    ap.add_argument("--platforms", nargs="+", default=["jax", "mlx"])
    ap.add_argument("--dtypes", nargs="+", default=["float32"], choices=["float32", "bfloat16"],
                    help="JAX compute dtypes to measure (MLX: float32 only)")
    ap.add_argument("--sizes", default="go1", choices=sorted(SIZES), help="task observation / action sizes")
    ap.add_argument("--images", type=_image_shape, default=(), metavar="HxWxC",
                    help="off-policy: a task with uint8 images of this shape (e.g. 64x64x12: 2 cameras x 2 frames)")
    ap.add_argument("--ppo_envs", type=int, default=1024, help="B of the PPO batch [24, B]")
    ap.add_argument("--offpolicy_batch", type=int, default=None, help="off-policy batch size (default: the "
                    "recipe's with --recipe, else 4096); a recipe's own batch_size wins over it")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--recipe", help="experiment script (e.g. experiments/fastsac_go1.py) whose RECIPE overrides the "
                    "defaults of the algorithms named by --algos")
    ap.add_argument("--config", action="append", default=[], help="algorithm override key=value after the recipe "
                    "(repeatable), e.g. updates_per_call=32")
    ap.add_argument("--profile_dir", default="", help="JAX: also trace 3 steady calls per algorithm and dtype with "
                    "jax.profiler into DIR/<algo>_<dtype> (TensorBoard/XProf trace plus a Perfetto JSON)")
    ap.add_argument("--out", default=os.path.join(REPO, "bench", "results", "learner_update_local.json"))
    args = ap.parse_args()
    recipe = {**(_recipe(args.recipe) if args.recipe else {}), **parse_overrides(args.config)}
    spec = _spec(args.sizes, args.images)
    if args.images:
        learners = [a for a in algos.names() if algos.info(a).images]
        no_images = [a for a in args.algos if a not in learners]
        if no_images:
            ap.error(f"--images: {', '.join(no_images)} learn no images ({', '.join(learners)} do)")
    rng = np.random.default_rng(0)
    rows = []
    for algo in args.algos:
        module = algos.get(algo)
        if module.BUFFER == "trajectory":
            config = apply_overrides(module.Config(), recipe)
            batch = _trajectory_batch(rng, config.horizon, args.ppo_envs, spec)
            steps = config.num_epochs * config.num_minibatches
            shape = f"[{config.horizon}, {args.ppo_envs}], {config.num_epochs}x{config.num_minibatches} minibatches"
        else:
            batch_size = args.offpolicy_batch or (None if args.recipe else 4096)  # None: the recipe's config
            config = apply_overrides(module.Config(), {**({"batch_size": batch_size} if batch_size else {}), **recipe})
            batch = _replay_batch(rng, config.updates_per_call, config.batch_size, spec)
            steps = config.updates_per_call
            shape = f"[{config.updates_per_call}, {config.batch_size}] ({config.updates_per_call} gradient steps)"
        for plat in args.platforms:
            for dtype in args.dtypes if plat == "jax" else ["float32"]:
                result = measure(algo, plat, batch, args.repeats, config, args.profile_dir, spec, dtype)
                result["gradient_steps_per_s"] = steps / result["steady_s"]
                rows.append({"algo": algo, "platform": plat, "dtype": dtype, "sizes": args.sizes, "batch": shape,
                             "gradient_steps_per_call": steps, **result})
                if args.images:
                    rows[-1]["images"] = "x".join(map(str, args.images))
                tf, tc = result["matmul_tflops_per_s"], result["conv_tflops_per_s"]
                print(f"{algo:9s} {plat:4s} {dtype:8s} {shape:48s} first {result['first_call_s']:7.2f} s  "
                      f"steady {result['steady_s'] * 1e3:9.1f} ms  {result['gradient_steps_per_s']:8.1f} grad steps/s"
                      + (f"  {tf:6.1f} matmul TFLOP/s" if tf is not None else "")
                      + (f"  {tc:6.1f} conv TFLOP/s" if tc else ""), flush=True)
    import jax

    machine = {"hostname": platform.node(), "date": datetime.datetime.now(datetime.timezone.utc).isoformat(),
               "cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
               "python": platform.python_version(), "jax": jax.__version__, "jax_devices": str(jax.devices()),
               "recipe": args.recipe, "config": args.config, "xla_flags": os.environ.get("XLA_FLAGS", "")}
    if "mlx" in args.platforms:
        import mlx.core as mx

        machine.update({"mlx": mx.__version__, "mlx_device": str(mx.default_device())})
    with open(args.out, "w") as f:
        json.dump({"machine": machine, "rows": rows}, f, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
