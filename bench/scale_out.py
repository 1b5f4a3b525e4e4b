"""Scaling out: FastSAC gradient steps/s on 1 vs N devices, and env steps/s with Ray nodes vs one host.

    # learner: FastSAC, Go1 sizes, batch 8192 per device (weak scaling), 1 device vs all local devices
    python bench/scale_out.py learner --devices 1 2 --out bench/results/scale_out_learner_h200x2.json
    # rollouts: one host's WorkerPool vs one pool per node of a running Ray cluster
    python bench/scale_out.py rollouts --ray_address auto --task go1_joystick_flat --num_workers 16 --envs_per_worker 64
    # both on this CPU machine: 2 emulated devices, a local 2-node cluster (1 CPU per node, 127.0.0.1 only)
    XLA_FLAGS=--xla_force_host_platform_device_count=2 python bench/scale_out.py learner --devices 1 2 \\
        --batch_per_device 1024
    RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 python bench/scale_out.py rollouts --local_nodes 2 --num_workers 1

Learner: ``sharding.make(learner, n)`` (the plain learner for n = 1, ``DataParallel`` otherwise) on a random
replay batch ``[U, n * batch_per_device]``; the first call (compile) is reported apart, steady state is the
median of ``--repeats`` waited calls; gradient steps/s = U / steady seconds, and the speed-up vs 1 device at
the same per-device batch. Emulated CPU devices share the same cores: their numbers test the code path, not
the scaling (that needs real accelerators).

Rollouts: random-initialised FastSAC policy in the workers, no learner; transitions received per second over
``--seconds`` after ``--warmup`` seconds, first with one host's ``WorkerPool`` (``--num_workers`` workers),
then with a ``RayPool`` over every node of the cluster (``--num_workers`` on the learner's node,
``--workers_per_host`` on each other), which ships them to this process's rings as a run does.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shutil
import socket
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO not in sys.path:
    sys.path.insert(0, REPO)

from bench.learner_update import SPEC as GO1  # noqa: E402  (Go1 sizes: actor 48, critic 123, 12 actions)
from bench.learner_update import _replay_batch  # noqa: E402
from bench.machine import cpu_model  # noqa: E402
from unilab_jax import algos  # noqa: E402
from unilab_jax.config import apply_overrides  # noqa: E402


def machine_info() -> dict:
    import jax

    cpu = cpu_model()
    return {"hostname": socket.gethostname(), "date": datetime.datetime.now(datetime.timezone.utc).isoformat(),
            "cpu_model": cpu, "cpu_count": os.cpu_count(), "python": platform.python_version(),
            "jax": jax.__version__, "jax_backend": jax.default_backend(),
            "jax_devices": [str(d) for d in jax.devices()], "xla_flags": os.environ.get("XLA_FLAGS", ""),
            "loadavg_at_end": list(os.getloadavg())}


def learner(args: argparse.Namespace) -> list[dict]:
    import jax

    from unilab_jax.training import sharding

    module = algos.get("fastsac")
    rows = []
    for n in args.devices:
        batch = args.batch_per_device * (n if args.device_split == "batch" else 1)
        config = apply_overrides(module.Config(), {"batch_size": batch, "compute_dtype": args.compute_dtype})
        plain = algos.make_learner(module, "jax", config, GO1)
        traced_in = plain.compute_dtype  # DataParallel compiles plain.traced_update, in this dtype
        lrn = sharding.make(plain, n, args.device_split)
        put = getattr(lrn, "from_numpy", jax.numpy.asarray)
        host = _replay_batch(np.random.default_rng(0), config.updates_per_call, config.batch_size)
        batch = {k: put(v) for k, v in host.items()}
        state = lrn.init(jax.random.key(0))
        t0 = time.perf_counter()
        state, metrics = lrn.update(state, batch)
        jax.block_until_ready((state, metrics))
        first = time.perf_counter() - t0
        times, returns = [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            state, metrics = lrn.update(state, batch)
            returns.append(time.perf_counter() - t0)
            jax.block_until_ready((state, metrics))
            times.append(time.perf_counter() - t0)
        if args.profile_dir:  # 3 more steady calls traced (kernels per device, collectives), after the timing
            with jax.profiler.trace(os.path.join(args.profile_dir, f"devices_{n}"), create_perfetto_trace=True):
                for _ in range(3):
                    state, metrics = lrn.update(state, batch)
                jax.block_until_ready((state, metrics))
        steady = float(np.median(times))
        rows.append({"devices": n, "device_split": args.device_split, "batch": config.batch_size,
                     "batch_per_device": args.batch_per_device,
                     "updates_per_call": config.updates_per_call, "compute_dtype": plain.compute_dtype,
                     "matmuls_traced_in": traced_in, "first_call_s": first,
                     "steady_s": steady, "returns_after_s": float(np.median(returns)),
                     "grad_steps_per_s": config.updates_per_call / steady,
                     "samples_per_s": config.updates_per_call * config.batch_size / steady})
    base = rows[0]["grad_steps_per_s"]
    print(f"{'devices':>7s} {'batch':>7s} {'first call s':>12s} {'steady ms':>10s} {'returns ms':>10s} "
          f"{'grad steps/s':>12s} {'x':>6s}")
    for r in rows:
        r["speedup"] = r["grad_steps_per_s"] / base
        print(f"{r['devices']:7d} {r['batch']:7d} {r['first_call_s']:12.2f} {r['steady_s'] * 1e3:10.1f} "
              f"{r['returns_after_s'] * 1e3:10.1f} "
              f"{r['grad_steps_per_s']:12.1f} {r['speedup']:6.2f}")
    return rows


def _rate(pool, warmup: float, seconds: float) -> float:
    time.sleep(warmup)
    s0, t0 = pool.env_steps(), time.monotonic()
    while time.monotonic() - t0 < seconds:
        time.sleep(0.1)
        pool._maybe_check_workers()
    return (pool.env_steps() - s0) / (time.monotonic() - t0)


def rollouts(args: argparse.Namespace) -> tuple[list[dict], dict]:
    cluster = None
    address = args.ray_address
    if args.local_nodes:  # started before jax is imported (Ray forks its processes)
        import tempfile

        # A private temp root (Ray writes its address file under $RAY_TMPDIR/ray and needs that folder).
        private = tempfile.mkdtemp(prefix="uray", dir="/tmp")
        os.environ.setdefault("RAY_TMPDIR", private)
        os.makedirs(os.path.join(os.environ["RAY_TMPDIR"], "ray"), exist_ok=True)
        from ray.cluster_utils import Cluster

        node = {"num_cpus": args.cpus_per_node, "node_ip_address": "127.0.0.1", "include_dashboard": False,
                "object_store_memory": 200 * 1024 * 1024, "temp_dir": os.path.join(os.environ["RAY_TMPDIR"], "ray")}
        cluster = Cluster(initialize_head=True, head_node_args=node)
        for _ in range(args.local_nodes - 1):
            cluster.add_node(**node)
        cluster.wait_for_nodes()
        address = cluster.address
    try:
        return _rollouts(args, address)
    finally:
        if cluster is not None:
            cluster.shutdown()
            shutil.rmtree(private, ignore_errors=True)


def _rollouts(args: argparse.Namespace, address: str) -> tuple[list[dict], dict]:
    import jax

    import tasks
    from unilab_jax import nets
    from unilab_jax.runtime.pool import WorkerPool
    from unilab_jax.runtime.ray_pool import RayPool

    module = algos.get("fastsac")
    probe = tasks.make(args.task, 1, 0, {})
    spec = probe.spec
    probe.close()
    lrn = algos.make_learner(module, "jax", module.Config(), spec)
    weights = nets.to_numpy(lrn.weights(lrn.init(jax.random.key(0))))
    kw = dict(task_name=args.task, envs_per_worker=args.envs_per_worker, algo_module=module.__name__,
              weight_template=weights, replay_capacity=args.replay_capacity)
    rows, cluster_info = [], {}
    pool = WorkerPool(num_workers=args.num_workers, **kw).start()
    try:
        pool.publish(weights, 0)
        rows.append({"setup": "one host (WorkerPool)", "hosts": 1, "workers": args.num_workers,
                     "env_steps_per_s": _rate(pool, args.warmup, args.seconds)})
    finally:
        pool.close()
    rp = RayPool(address, num_workers=args.num_workers, workers_per_host=args.workers_per_host or None, **kw)
    try:
        rp.start()
        rp.publish(weights, 0)
        rate = _rate(rp, args.warmup, args.seconds)
        rows.append({"setup": f"Ray, {len(rp.hosts)} node(s)", "hosts": len(rp.hosts), "workers": rp.num_workers,
                     "env_steps_per_s": rate, "rows_overrun": rp.overrun})
        cluster_info = {"address": address, "hosts": rp.hosts, "local_nodes": args.local_nodes}
    finally:
        rp.close()
    base = rows[0]["env_steps_per_s"]
    print(f"{'setup':28s} {'hosts':>5s} {'workers':>7s} {'env steps/s':>12s} {'x':>6s}")
    for r in rows:
        r["speedup"] = r["env_steps_per_s"] / base
        print(f"{r['setup']:28s} {r['hosts']:5d} {r['workers']:7d} {r['env_steps_per_s']:12.0f} {r['speedup']:6.2f}")
    return rows, cluster_info


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("part", choices=["learner", "rollouts"])
    ap.add_argument("--devices", type=int, nargs="+", default=[1, 2], help="learner: device counts (first: baseline)")
    ap.add_argument("--batch_per_device", type=int, default=8192,
                    help="learner: minibatch rows per device (with --device_split=critics: the whole minibatch)")
    ap.add_argument("--device_split", default="batch", choices=["batch", "critics"],
                    help="learner: split the minibatch over the devices, or the critic ensemble (training/sharding.py)")
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--ray_address", default="auto", help="rollouts: the cluster (ignored with --local_nodes)")
    ap.add_argument("--local_nodes", type=int, default=0, help="rollouts: start a local cluster of this many nodes")
    ap.add_argument("--cpus_per_node", type=int, default=1, help="rollouts: CPUs of each --local_nodes node")
    ap.add_argument("--task", default="cartpole_balance")
    ap.add_argument("--num_workers", type=int, default=2)
    ap.add_argument("--workers_per_host", type=int, default=0, help="workers on each other node (0: --num_workers)")
    ap.add_argument("--envs_per_worker", type=int, default=32)
    ap.add_argument("--replay_capacity", type=int, default=200_000, help="rollouts: ring rows per worker")
    ap.add_argument("--warmup", type=float, default=5.0)
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--compute_dtype", default="auto", choices=["auto", "float32", "bfloat16"],
                    help="learner: FastSAC's compute_dtype (auto: bfloat16 on a GPU)")
    ap.add_argument("--profile_dir", default="", help="learner: also trace 3 steady calls per device count with "
                    "jax.profiler into DIR/devices_<n> (read with bench/trace_summary.py)")
    ap.add_argument("--out", default="")
    args = ap.parse_args()
    record: dict = {"command": " ".join(sys.argv), "part": args.part, "loadavg_at_start": list(os.getloadavg())}
    if args.part == "learner":
        record["rows"] = learner(args)
    else:
        record["rows"], record["cluster"] = rollouts(args)
    record["machine"] = machine_info()
    out = args.out or os.path.join(REPO, "bench", "results", f"scale_out_{args.part}_{socket.gethostname()}.json")
    with open(out, "w") as f:
        json.dump(record, f, indent=2)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
