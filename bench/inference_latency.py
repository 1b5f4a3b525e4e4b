"""On-robot inference latency of every locomotion recipe's exported actor: one observation, one CPU core.

    python bench/inference_latency.py --out bench/results/inference_latency_local.json

For each recipe of ``experiments/`` that trains on Go1 / Go2 / G1 (the CPU-worker scripts; HORA gives two
actors, teacher and student), the actor is built at the recipe's sizes (the JAX learner's published weights
at init; latency does not depend on the values; the HORA student's adaptation module at ``hora_cli``'s
defaults, 30 frames), exported with ``unilab_jax.apps.export`` and timed on single observations ``[1, obs_dim]``:

* ``numpy``: the generated numpy module (``Policy()(obs)``);
* ``onnx``: onnxruntime, ``intra_op_num_threads=1``, ``inter_op_num_threads=1``, sequential execution;
* ``act``: the training-time worker policy (``algo.act(weights, obs, noise, deterministic=True)``), for reference.

The process is pinned to one core (``os.sched_setaffinity``; the last usable one unless ``--core``) and
BLAS to one thread. Each path is warmed up, then ``--calls`` calls are timed one by one
(``time.perf_counter_ns``); p50 and p99 in microseconds. Prints a table, writes JSON with machine info
(``bench/throughput.py``'s, with the load average at start and end).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # before numpy is imported
    os.environ[_var] = "1"

import argparse  # noqa: E402
import importlib  # noqa: E402
import importlib.util  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
for _p in (REPO, HERE, os.path.join(REPO, "experiments")):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import numpy as np  # noqa: E402
from machine import write_json  # noqa: E402
from throughput import machine_info  # noqa: E402

STUDENT_HISTORY = 30  # hora_cli's --history_len default


def recipes() -> list[tuple[str, str, str, dict, dict]]:
    """(script, algorithm, task, algorithm recipe, task recipe) of every CPU locomotion recipe (unilab_jax.recipes)."""
    from unilab_jax import recipes as table

    out = []
    for name in table.names():
        if "mjx" in name or not re.search(r"go1|go2|g1", name):
            continue
        r = table.get(name)
        script = f"{name}.py"
        if r.launcher == "run_hora":
            out.append((script, "hora_teacher", r.task, r.recipe, {**r.task_recipe, "history_len": 1}))
            out.append((script, "hora_student", r.task, dict(r.kwargs["student_recipe"]),
                        {**r.task_recipe, "history_len": STUDENT_HISTORY}))
            continue
        out.append((script, r.algo, r.task, r.recipe, r.task_recipe))
    return out


def published_weights(algo: str, task: str, recipe: dict, task_recipe: dict) -> tuple[object, dict, int]:
    """(declaration module, numpy weights as published to the workers, obs_dim)."""
    import jax

    import tasks
    from unilab_jax import algos, nets
    from unilab_jax import xp as shim
    from unilab_jax.config import apply_overrides

    if algo == "hora_student":  # its learner starts from a teacher checkpoint: build the published layout
        from unilab_jax import nets_temporal
        from unilab_jax.algos.hora import common

        teacher, tw, _ = published_weights("hora_teacher", task, _teacher_recipe(), {**task_recipe, "history_len": 1})
        spec = tasks.make(task, 1, overrides=task_recipe).spec
        module = algos.get(algo)
        cfg = apply_overrides(module.Config(), recipe)
        d, p, z = common.teacher_dims(tw)
        adapt = nets_temporal.adaptation_init(shim.get("numpy").random.key(0), d, z, spec.history_len,
                                              shim.get("numpy"), cfg.adapt_hidden, cfg.conv_channels, cfg.conv_kernels)
        weights = {"actor": tw["actor"], "log_std": tw["log_std"], "adapt": adapt,
                   "history_norm": common.history_stats(tw["obs_norm"], d, p, spec.history_len),
                   "noise_scale": np.float32(0.0)}
        return module, weights, spec.obs_dim
    spec = tasks.make(task, 1, overrides=task_recipe).spec
    module = algos.get(algo)
    learner = algos.make_learner(module, "jax", apply_overrides(module.Config(), recipe), spec)
    return module, nets.to_numpy(learner.weights(learner.init(jax.random.key(0)))), spec.obs_dim


def _teacher_recipe() -> dict:
    from unilab_jax import recipes as table

    return table.get("hora_go1").recipe


def percentiles(fn, obs: np.ndarray, calls: int, warmup: int) -> dict[str, float]:
    for _ in range(warmup):
        fn(obs)
    times = np.empty(calls)
    for i in range(calls):
        t = time.perf_counter_ns()
        fn(obs)
        times[i] = time.perf_counter_ns() - t
    return {"p50_us": float(np.percentile(times, 50) / 1e3), "p99_us": float(np.percentile(times, 99) / 1e3)}


def measure(script: str, algo: str, task: str, recipe: dict, task_recipe: dict, tmp: str, calls: int,
            warmup: int) -> dict:
    """One recipe's row: export its actor both ways and time the three paths on one observation."""
    import onnxruntime as ort

    from unilab_jax.apps import export

    module, weights, obs_dim = published_weights(algo, task, recipe, task_recipe)
    graph, out = export.actor_graph(algo, weights, obs_dim)
    noise = np.zeros((1, 64), np.float32)  # deterministic: read by no actor, wide enough for any
    action_dim = int(np.shape(module.act(weights, np.zeros((1, obs_dim), np.float32), noise, True)[0])[-1])
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    session = ort.InferenceSession(export.to_onnx(graph, out, obs_dim, action_dim).SerializeToString(), opts,
                                   providers=["CPUExecutionProvider"])
    py, _ = export.to_numpy_module(graph, out, obs_dim, action_dim, os.path.join(tmp, f"{algo}_{task}.py"))
    spec = importlib.util.spec_from_file_location(f"bench_{algo}_{task}", py)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    policy = mod.Policy()
    obs = np.random.default_rng(0).normal(size=(1, obs_dim)).astype(np.float32)
    return {"recipe": script, "algo": algo, "task": task, "obs_dim": obs_dim, "action_dim": action_dim,
            "graph_nodes": len(graph.nodes), "params": int(sum(np.size(v) for v in graph.consts.values())),
            "numpy": percentiles(policy, obs, calls, warmup),
            "onnx": percentiles(lambda o: session.run(["action"], {"obs": o}), obs, calls, warmup),
            "act": percentiles(lambda o: module.act(weights, o, noise[:, :action_dim], True), obs, calls, warmup)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--core", type=int, default=None, help="CPU core to pin to (default: the last usable one)")
    ap.add_argument("--out", default=os.path.join(HERE, "results", "inference_latency_local.json"))
    args = ap.parse_args()
    if args.calls < 100 or args.warmup < 0:
        ap.error("--calls must be at least 100 and --warmup >= 0")
    import onnxruntime as ort

    machine = machine_info()
    core = args.core if args.core is not None else max(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for script, algo, task, recipe, task_recipe in recipes():
            row = measure(script, algo, task, recipe, task_recipe, tmp, args.calls, args.warmup)
            rows.append(row)
            print(f"{script:18s} {algo:13s} obs {row['obs_dim']:4d}  params {row['params']:8,d}  "
                  + "  ".join(f"{k} p50 {row[k]['p50_us']:7.1f} p99 {row[k]['p99_us']:7.1f} us"
                              for k in ("numpy", "onnx", "act")), flush=True)
    machine["loadavg_at_end"] = list(os.getloadavg())
    write_json(args.out, {"machine": machine, "config": {**vars(args), "core": core,
                                                         "onnxruntime": ort.__version__}, "results": rows})


if __name__ == "__main__":
    main()
