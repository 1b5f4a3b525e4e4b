"""Rollout throughput: raw MuJoCo ceiling vs the WorkerPool, measured in the same run.

    python bench/throughput.py --task go1_joystick_flat --num_workers 2 --envs_per_worker 256 \\
        --seconds 20 --out bench/results/go1_2w.json

Phases (each timed for ``--seconds``, after a warm-up):

(a) **Ceiling.** ``mujoco.mj_step`` in a plain Python loop on the task's own compiled model (the
    nominal model, no domain randomisation) and one ``MjData``, reset to the first keyframe every
    ``episode_length * substeps`` physics steps, control held at the keyframe's ``ctrl``.
    Measured twice: ``ceiling_1proc``, one process alone (the per-core rate), and
    ``ceiling_parallel``, ``--num_workers`` processes started together behind a barrier, each
    timing its own loop; their rates are summed. Env steps/s = physics steps/s / substeps.
    ``task_alone``: the same ``--num_workers`` parallel processes each stepping the task itself
    (``tasks.make(task, M).step`` with uniform random actions: its physics engine, domain
    randomisation, observation / reward math and resets) without the runtime or a policy.
    Tasks step physics with ``mujoco.rollout`` (a C loop over the batch), so they can beat the
    Python ``mj_step`` loop of the ceiling.
(b) **Pool.** ``WorkerPool`` with ``--num_workers`` x ``--envs_per_worker`` envs running the
    numpy MLP policy of ``bench/bench_policy.py`` (512-256-128, asynchronous, trajectory slots of
    ``--horizon`` steps). The learner only drains slots (copies them out and releases them) and
    publishes new dummy weights every ``--publish_every`` seconds. Env steps/s comes from the
    workers' own counters over the timed window.

Prints a table and writes JSON (with CPU model, cores, python / numpy / mujoco versions, hostname,
date) to ``--out`` (default ``bench/results/<task>_<W>w_<M>e.json``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import multiprocessing as mp
import os
import platform
import socket
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
for p in (REPO, HERE):  # the repo root (tasks, unilab_jax) and bench/ (bench_policy) for the workers
    if p not in sys.path:
        sys.path.insert(0, p)
_robots = os.path.join(os.path.dirname(REPO), "shared", "robots")
if "MENAGERIE_ROOT" not in os.environ and os.path.isdir(_robots):
    os.environ["MENAGERIE_ROOT"] = _robots  # offline Menagerie copy, as the Makefile sets it

import numpy as np  # noqa: E402

from bench.machine import cpu_model  # noqa: E402


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="go1_joystick_flat")
    ap.add_argument("--task_overrides", nargs="*", default=[], help="key=value task config overrides")
    ap.add_argument("--num_workers", type=int, default=len(os.sched_getaffinity(0)))
    ap.add_argument("--envs_per_worker", type=int, default=256)
    ap.add_argument("--horizon", type=int, default=24)
    ap.add_argument("--slots_per_worker", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=20.0, help="timed window of each phase")
    ap.add_argument("--warmup", type=float, default=3.0, help="untimed seconds before each pool window")
    ap.add_argument("--publish_every", type=float, default=0.5, help="seconds between dummy weight publishes")
    ap.add_argument("--pin_cpus", type=int, default=-1, help="pool phase: -1 no worker affinity; K >= 0: workers "
                    "pinned to their shares of the usable cores except the first K (runtime/spawn.py cpu_placement)")
    ap.add_argument("--skip_ceiling", action="store_true")
    ap.add_argument("--skip_task", action="store_true")
    ap.add_argument("--skip_pool", action="store_true")
    ap.add_argument("--out", default=None, help="JSON path (default bench/results/<task>_<W>w_<M>e.json)")
    args = ap.parse_args(argv)
    if args.num_workers <= 0 or args.envs_per_worker <= 0 or args.seconds <= 0:
        ap.error("--num_workers, --envs_per_worker and --seconds must be positive")
    return args


# ---------------------------------------------------------------------------------------------
# Machine info
# ---------------------------------------------------------------------------------------------
def machine_info() -> dict:
    import mujoco

    cpu = cpu_model()
    return {
        "hostname": socket.gethostname(),
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "cpu_model": cpu,
        "cpu_count": os.cpu_count(),
        "cpus_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "loadavg_at_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "mujoco": mujoco.__version__,
    }


# ---------------------------------------------------------------------------------------------
# (a) Raw mj_step ceiling
# ---------------------------------------------------------------------------------------------
def _model_and_substeps(task_name: str, overrides: dict):
    import tasks

    task = tasks.make(task_name, 1, 0, overrides)
    model = task.model
    substeps = int(round(task.spec.ctrl_dt / model.opt.timestep))
    episode = task.spec.episode_length
    task.close()
    return model, substeps, episode


def _mj_loop(task_name: str, overrides: dict, seconds: float, barrier, results) -> None:
    import mujoco

    model, substeps, episode = _model_and_substeps(task_name, overrides)
    data = mujoco.MjData(model)

    def reset():
        if model.nkey:
            mujoco.mj_resetDataKeyframe(model, data, 0)
        else:
            mujoco.mj_resetData(model, data)
        mujoco.mj_forward(model, data)

    reset()
    every = episode * substeps
    for _ in range(200):  # warm-up
        mujoco.mj_step(model, data)
    if barrier is not None:
        barrier.wait()
    n, t0 = 0, time.perf_counter()
    deadline = t0 + seconds
    while True:
        for _ in range(100):
            mujoco.mj_step(model, data)
        n += 100
        if n % every < 100:
            reset()
        if time.perf_counter() >= deadline:
            break
    dt = time.perf_counter() - t0
    results.put({"steps": n, "seconds": dt, "per_s": n / dt, "substeps": substeps})


def _task_loop(task_name: str, overrides: dict, num_envs: int, seconds: float, barrier, results) -> None:
    import tasks

    task = tasks.make(task_name, num_envs, 0, overrides)
    rng = np.random.default_rng(0)
    task.reset()
    shape = (num_envs, task.spec.action_dim)
    for _ in range(5):
        task.step(rng.uniform(-1, 1, shape).astype(np.float32))
    if barrier is not None:
        barrier.wait()
    n, t0 = 0, time.perf_counter()
    deadline = t0 + seconds
    while time.perf_counter() < deadline:
        task.step(rng.uniform(-1, 1, shape).astype(np.float32))
        n += num_envs
    dt = time.perf_counter() - t0
    task.close()
    results.put({"steps": n, "seconds": dt, "per_s": n / dt})


def _parallel(target, args: tuple, n_procs: int, seconds: float) -> list[dict]:
    """Runs ``target(*args, barrier, results)`` in ``n_procs`` spawned processes started together."""
    ctx = mp.get_context("spawn")
    results = ctx.Queue()
    barrier = ctx.Barrier(n_procs) if n_procs > 1 else None
    procs = [ctx.Process(target=target, args=(*args, barrier, results)) for _ in range(n_procs)]
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the WorkerPool does for its workers
    for p in procs:
        p.start()
    got = [results.get(timeout=seconds + 300) for _ in procs]
    for p in procs:
        p.join(30)
    return got


def ceiling(task_name: str, overrides: dict, n_procs: int, seconds: float) -> dict:
    got = _parallel(_mj_loop, (task_name, overrides, seconds), n_procs, seconds)
    substeps = got[0]["substeps"]
    per_proc = [g["per_s"] for g in got]
    total = float(sum(per_proc))
    return {
        "processes": n_procs,
        "substeps": substeps,
        "physics_steps_per_s_per_proc": per_proc,
        "physics_steps_per_s": total,
        "env_steps_per_s": total / substeps,
    }


def task_alone(task_name: str, overrides: dict, n_procs: int, num_envs: int, seconds: float) -> dict:
    got = _parallel(_task_loop, (task_name, overrides, num_envs, seconds), n_procs, seconds)
    per_proc = [g["per_s"] for g in got]
    return {"processes": n_procs, "envs_per_process": num_envs, "env_steps_per_s_per_proc": per_proc,
            "env_steps_per_s": float(sum(per_proc))}


# ---------------------------------------------------------------------------------------------
# (b) WorkerPool
# ---------------------------------------------------------------------------------------------
def pool_throughput(args, overrides: dict) -> dict:
    import bench_policy

    import tasks
    from unilab_jax.runtime import WorkerPool
    from unilab_jax.runtime.spawn import cpu_placement

    probe = tasks.make(args.task, 1, 0, overrides)
    spec = probe.spec
    probe.close()
    weights = bench_policy.init_weights(spec.obs_dim, spec.action_dim)
    t_build = time.monotonic()
    pool = WorkerPool(args.task, overrides, num_workers=args.num_workers, envs_per_worker=args.envs_per_worker,
                      seed=0, algo_module="bench_policy", weight_template=weights, horizon=args.horizon,
                      slots_per_worker=args.slots_per_worker,
                      worker_cpus=cpu_placement(args.num_workers, args.pin_cpus) if args.pin_cpus >= 0 else None)
    try:
        pool.start(timeout=600)
        startup = time.monotonic() - t_build
        version = 0
        pool.publish(weights, version)
        last_pub = time.monotonic()

        def drain(seconds: float) -> dict:
            nonlocal version, last_pub
            n_slots, wait_s, copy_s, lag = 0, 0.0, 0.0, []
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                _, info = pool.collect(n_slots=1, timeout=120)
                n_slots += 1
                wait_s += info["wait_s"]
                copy_s += info["copy_s"]
                lag.append(version - info["policy_version_min"])
                if time.monotonic() - last_pub > args.publish_every:
                    version += 1
                    weights["log_std"][:] = -0.01 * (version % 50)
                    pool.publish(weights, version)
                    last_pub = time.monotonic()
            return {"slots": n_slots, "wait_s": wait_s, "copy_s": copy_s,
                    "mean_policy_lag": float(np.mean(lag)) if lag else float("nan")}

        drain(args.warmup)
        pool.stats()  # reset the rate window
        t0 = time.monotonic()
        s0 = pool.env_steps()
        learner = drain(args.seconds)
        dt = time.monotonic() - t0
        steps = pool.env_steps() - s0
        stats = pool.stats()
        slot_mb = sum(int(np.prod(s)) * d.itemsize for s, d in pool.fields.values()) * args.horizon \
            * args.envs_per_worker / 2**20
        return {
            "env_steps": steps,
            "seconds": dt,
            "env_steps_per_s": steps / dt,
            "startup_s": startup,
            "slot_mib": slot_mb,
            "publishes": version,
            "weight_read_retries": stats["weight_read_retries"],
            "workers_with_jax": stats["workers_with_jax"],
            "learner": learner,
        }
    finally:
        pool.close()


def main(argv=None) -> dict:
    args = parse_args(argv)
    from unilab_jax.config import parse_overrides

    overrides = parse_overrides(args.task_overrides)
    out_path = args.out or os.path.join(
        HERE, "results", f"{args.task}_{args.num_workers}w_{args.envs_per_worker}e.json")
    result = {"machine": machine_info(), "config": vars(args) | {"task_overrides": overrides}}
    print(f"# {args.task}: {args.num_workers} workers x {args.envs_per_worker} envs, {args.seconds:.0f} s per "
          f"phase on {result['machine']['cpu_model']} ({result['machine']['cpus_usable']} usable cores, "
          f"load {result['machine']['loadavg_at_start']})", flush=True)
    rows = []
    if not args.skip_ceiling:
        c1 = ceiling(args.task, overrides, 1, args.seconds)
        result["ceiling_1proc"] = c1
        rows.append(("ceiling: mj_step, 1 process", c1["physics_steps_per_s"], c1["env_steps_per_s"]))
        cp = ceiling(args.task, overrides, args.num_workers, args.seconds)
        result["ceiling_parallel"] = cp
        rows.append((f"ceiling: mj_step, {args.num_workers} processes", cp["physics_steps_per_s"],
                     cp["env_steps_per_s"]))
    if not args.skip_task:
        ta = task_alone(args.task, overrides, args.num_workers, args.envs_per_worker, args.seconds)
        result["task_alone"] = ta
        sub = result.get("ceiling_parallel", {}).get("substeps")
        rows.append((f"task.step alone, {args.num_workers}x{args.envs_per_worker}, random actions",
                     ta["env_steps_per_s"] * sub if sub else float("nan"), ta["env_steps_per_s"]))
    if not args.skip_pool:
        p = pool_throughput(args, overrides)
        result["pool"] = p
        sub = result.get("ceiling_parallel", {}).get("substeps")
        rows.append((f"WorkerPool {args.num_workers}x{args.envs_per_worker} + numpy MLP",
                     p["env_steps_per_s"] * sub if sub else float("nan"), p["env_steps_per_s"]))
        if "ceiling_parallel" in result:
            p["fraction_of_parallel_ceiling"] = p["env_steps_per_s"] / result["ceiling_parallel"]["env_steps_per_s"]
        if "task_alone" in result:
            p["fraction_of_task_alone"] = p["env_steps_per_s"] / result["task_alone"]["env_steps_per_s"]
    print(f"{'phase':<46} {'physics steps/s':>16} {'env steps/s':>12}")
    for name, phys, env in rows:
        print(f"{name:<46} {phys:>16,.0f} {env:>12,.0f}")
    if "pool" in result:
        p = result["pool"]
        frac, frac_task = p.get("fraction_of_parallel_ceiling"), p.get("fraction_of_task_alone")
        print("pool: " + (f"{frac:.0%} of the mj_step ceiling, " if frac else "")
              + (f"{frac_task:.0%} of the task alone; " if frac_task else ""), end="")
        print(f"startup {p['startup_s']:.1f} s, slot {p['slot_mib']:.1f} MiB, learner waited "
              f"{p['learner']['wait_s']:.1f} s and copied {p['learner']['copy_s']:.2f} s over "
              f"{p['learner']['slots']} slots; {p['publishes']} publishes, mean policy lag "
              f"{p['learner']['mean_policy_lag']:.2f} versions")
    os.makedirs(os.path.dirname(os.path.abspath(out_path)), exist_ok=True)
    with open(out_path, "w") as f:
        json.dump(result, f, indent=2, default=float)
    print(f"wrote {out_path}")
    return result


if __name__ == "__main__":
    main()
