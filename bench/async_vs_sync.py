"""The asynchronous robot-learning pipeline against its synchronous twin (RLinf-USER's comparison).

    MENAGERIE_ROOT=../shared/robots python bench/async_vs_sync.py --robots=2 --speed=1 --seconds=240 \\
        --policies=sac,sacflow_large --sync_mb=256 --out=bench/results/async_vs_sync_h100.json

Both pipelines drive the same robots (``--robots`` simulated Frankas on pick-and-place behind robot servers
started here at ``--speed`` times real time, ``--episode_length`` steps per episode) with the same learner,
batch and weights:

* ``async`` (the runtime as it is): a worker process steps the robots and writes replay rows while the
  learner samples ``[U, B]`` batches and updates back to back, publishing weights every
  ``--publish_every`` updates; collection, training and weight sync overlap (weights of 8 MiB and more
  are written by a background thread, as the trainer does; ``--publish_inline`` writes them in the loop).
* ``sync`` (in turn): collect one episode on every robot (the same worker code, run in this process),
  then train ``utd x`` the new transitions, then sync the weights, then collect again; the robots wait
  while the learner trains and the weights travel. ``--utd=1,2,4`` measures it at each ratio against one
  async run: the two metrics trade through the sync pipeline's training share (docs/BENCHMARKS.md).

The published weights carry ``--sync_mb`` MB of ballast beside the policy, so every weight sync moves the
bytes of a large model (a VLA-sized actor) through the weight channel; the worker reads each new version
(async: while collecting). Policies (``POLICIES``): ``sac`` (state SAC, 256x256 MLPs), ``sac_cnn`` (SAC from
64 px camera images through DrQ's encoder: the servers render the front camera) and ``sacflow_large``
(SAC Flow, K = 8 steps, 1024x1024x1024 velocity network: a large policy's update cost).

Metrics (RLinf-USER's two, over the whole measured window after ``--warmup_s``): collection seconds per
episode = window wall seconds / episodes collected per robot (env steps / ``--episode_length``: counting only
completed episodes rounds a short window's 5-6 episodes per robot by up to one, ~20%; that count is kept as
``collection_s_per_episode_completed``), and training seconds per update = window
wall seconds / learner updates (U gradient steps each); plus the phase split of the sync pipeline and the
speed-ups (sync / async). JSON with machine info under bench/results/.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from time_to_target import machine_info  # noqa: E402

POLICIES = {
    "sac": ("sac", dict(actor_hidden=(256, 256), critic_hidden=(256, 256))),
    "sac_cnn": ("sac", dict(actor_hidden=(256, 256), critic_hidden=(256, 256))),
    "sacflow_large": ("sacflow", dict(actor_hidden=(1024, 1024, 1024), critic_hidden=(256, 256), flow_steps=8)),
}
# Image SAC (CNN): the front camera's last 3 frames at 64 x 64 (uint8 [64, 64, 9]) through DrQ's encoder (the
# SAC family's defaults: four 3x3 32-channel convolutions, strides 2, 1, 1, 1, 50 features) beside proprioception.
IMAGE_TASKS = {"sac_cnn": {"cameras": ("front",), "image_size": 64, "frame_stack": 3}}
COMMON = dict(updates_per_call=4, learning_starts=256, replay_capacity=100_000)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=2, help="simulated Franka robot servers")
    ap.add_argument("--speed", type=float, default=1.0, help="robot speed (1: real time)")
    ap.add_argument("--episode_length", type=int, default=100)
    ap.add_argument("--seconds", type=float, default=240.0, help="measured wall seconds per pipeline and policy")
    ap.add_argument("--warmup_s", type=float, default=20.0, help="wall seconds before the window (compile, fill)")
    ap.add_argument("--policies", default="sac,sacflow_large")
    ap.add_argument("--modes", default="async,sync")
    ap.add_argument("--sync_mb", type=float, default=256.0, help="MB of weights each sync moves")
    ap.add_argument("--publish_every", type=int, default=8, help="async: updates between weight publications")
    ap.add_argument("--publish_inline", action="store_true",
                    help="async: the learner writes each version itself (default: as the trainer, a background "
                         "thread writes weights of PREFETCH_MIN_BYTES and more)")
    ap.add_argument("--utd", default="1", help="sync: gradient steps per collected transition; a comma list runs the "
                    "sync pipeline once per ratio against one async run (the async learner trains back to back)")
    ap.add_argument("--batch_size", type=int, default=256)
    ap.add_argument("--platform", default="jax", choices=("jax", "mlx"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="bench/results/async_vs_sync_local.json")
    args = ap.parse_args(argv)
    args.policies = [p for p in args.policies.split(",") if p]
    args.modes = [m for m in args.modes.split(",") if m]
    try:
        args.utd = [float(u) for u in str(args.utd).split(",") if u]
    except ValueError:
        ap.error(f"--utd: comma-separated numbers, got {args.utd!r}")
    bad = [p for p in args.policies if p not in POLICIES] + [m for m in args.modes if m not in ("async", "sync")]
    if bad or not args.policies or not args.modes:
        ap.error(f"unknown or empty --policies/--modes {bad}; policies: {sorted(POLICIES)}, modes: async, sync")
    if (args.robots < 1 or not args.speed > 0 or args.seconds <= 0 or args.sync_mb < 0 or args.episode_length < 1
            or not args.utd or min(args.utd) <= 0 or args.batch_size < 1):
        ap.error("--robots, --speed, --seconds, --episode_length, --utd, --batch_size must be positive, --sync_mb >= 0")
    return args


class Learner:
    """The registry's learner of a policy, its weights with the sync ballast, and timed updates."""

    def __init__(self, policy: str, spec, args: argparse.Namespace, utd: float):
        from unilab_jax import algos, nets

        name, overrides = POLICIES[policy]
        self.module = algos.get(name)
        self.config = self.module.Config(**{**COMMON, **overrides, "batch_size": args.batch_size, "utd": utd})
        self.learner = algos.make_learner(name, args.platform, self.config, spec)
        self.platform = args.platform
        if args.platform == "jax":
            import jax

            self.state = self.learner.init(jax.random.key(args.seed))
        else:
            self.state = self.learner.init(args.seed)
        self.ballast = np.zeros(int(args.sync_mb * 2**20 / 4), np.float32)
        self._nets = nets
        self.version = 0

    def weights(self) -> dict:
        w = self._nets.to_numpy(self.learner.weights(self.state))
        self.version += 1
        # A new payload each version (the channel checksums it). The publishing thread may still be copying
        # the last version's ballast: then that copy gets this word, which changes nothing measured.
        self.ballast[:1] = self.version
        return {**w, "ballast": self.ballast}

    def update(self, batch: dict) -> None:
        self.state, metrics = self.learner.update(self.state, batch)
        if self.platform == "jax":
            import jax

            jax.block_until_ready(metrics)


def _batch(pool, learner: Learner, rng: np.random.Generator, serial: bool) -> dict:
    from unilab_jax.fields import replay_fields

    u, b = learner.config.updates_per_call, learner.config.batch_size
    rows = pool.sample(u * b, rng, serial_steps=0) if serial else pool.sample(u * b, rng)
    return {k: rows[k].reshape(u, b, *rows[k].shape[1:]) for k in replay_fields(pool.spec)}


def run(mode: str, policy: str, addresses: list[str], args: argparse.Namespace, utd: float | None = None) -> dict:
    """One measured window of ``mode`` (``utd``: the sync pipeline's ratio; None for async)."""
    from unilab_jax.runtime.pool import WorkerPool
    from unilab_jax.runtime.weights import WeightPublisher
    from unilab_jax.runtime.worker import PREFETCH_MIN_BYTES

    serial = mode == "sync"
    overrides = {"robots": tuple(addresses), "episode_length": args.episode_length, **IMAGE_TASKS.get(policy, {})}
    import tasks

    probe = tasks.make("robot_pick_place", 1, args.seed, overrides)  # the spec (claims one robot, releases it)
    spec = probe.spec
    probe.close()
    learner = Learner(policy, spec, args, utd or 1.0)
    first = learner.weights()
    pool = WorkerPool("robot_pick_place", overrides, num_workers=1, envs_per_worker=len(addresses),
                      algo_module=learner.module.__name__, weight_template=first,
                      replay_capacity=COMMON["replay_capacity"], serial=serial)
    rng = np.random.default_rng(args.seed)
    phases = {"collect_s": 0.0, "train_s": 0.0, "sync_s": 0.0}
    with pool:
        pool.start()
        pool.publish(first, learner.version)
        publisher = (WeightPublisher(pool.publish) if not serial and not args.publish_inline
                     and pool.weights.nbytes >= PREFETCH_MIN_BYTES else None)
        t_start = time.perf_counter()
        t_window = t_end = None
        updates = episodes0 = steps0 = 0
        while True:
            now = time.perf_counter()
            if t_window is None and now - t_start >= args.warmup_s and pool.replay_size() >= learner.config.batch_size:
                stats = pool.stats()
                t_window, updates, episodes0, steps0 = now, 0, stats["episodes"], stats["env_steps"]
                phases = dict.fromkeys(phases, 0.0)
            if t_window is not None and now - t_window >= args.seconds:
                t_end = now
                break
            if serial:  # collect one episode on every robot, train on it, sync, in turn
                t0 = time.perf_counter()
                pool.pump(args.episode_length)
                t1 = time.perf_counter()
                n_updates = max(math.ceil(learner.config.utd * args.episode_length * len(addresses)
                                          / learner.config.updates_per_call), 1)
                if pool.replay_size() >= learner.config.batch_size:
                    for _ in range(n_updates):
                        learner.update(_batch(pool, learner, rng, True))
                        updates += 1
                t2 = time.perf_counter()
                pool.publish(learner.weights(), learner.version)  # the worker reads it at its next step
                phases["collect_s"] += t1 - t0
                phases["train_s"] += t2 - t1
                phases["sync_s"] += time.perf_counter() - t2
            else:  # the learner trains back to back while the worker collects
                if pool.replay_size() < learner.config.batch_size:
                    time.sleep(0.05)
                    continue
                t0 = time.perf_counter()
                learner.update(_batch(pool, learner, rng, False))
                updates += 1
                t1 = time.perf_counter()
                phases["train_s"] += t1 - t0
                if updates % args.publish_every == 0:
                    (publisher.submit if publisher is not None else pool.publish)(learner.weights(), learner.version)
                    phases["sync_s"] += time.perf_counter() - t1
        stats = pool.stats()
        episodes, steps = stats["episodes"] - episodes0, stats["env_steps"] - steps0
        if publisher is not None:
            publisher.close()
    window = t_end - t_window
    per_robot = steps / args.episode_length / len(addresses)  # episodes' worth of steps: no whole-episode rounding
    return {"mode": mode, "policy": policy, "utd": utd, "window_s": window, "episodes": episodes, "env_steps": steps,
            "updates": updates, "collection_s_per_episode": window / per_robot if per_robot else float("inf"),
            "collection_s_per_episode_completed": window / (episodes / len(addresses)) if episodes else float("inf"),
            "training_s_per_update": window / updates if updates else float("inf"),
            "gradient_steps_per_update": learner.config.updates_per_call, **phases}


def speedups(results: list[dict]) -> list[dict]:
    """One row per sync run (policy, its utd): sync / async collection seconds per episode and training seconds
    per update, against the same policy's async run (none without one)."""
    rows = []
    for s in (r for r in results if r["mode"] == "sync"):
        a = next((r for r in results if r["policy"] == s["policy"] and r["mode"] == "async"), None)
        if a is not None:
            rows.append({"policy": s["policy"], "utd": s["utd"],
                         "collection": s["collection_s_per_episode"] / a["collection_s_per_episode"],
                         "training": s["training_s_per_update"] / a["training_s_per_update"]})
    return rows


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    from unilab_jax.robots import inventory

    entries = inventory.parse(",".join(["sim:franka_emika_panda"] * args.robots))
    results = []
    for policy in args.policies:  # servers per policy: only an image policy's servers render
        image = IMAGE_TASKS.get(policy, {})
        with inventory.Inventory(entries, "pick_place", args.speed, seed=args.seed, cameras=image.get("cameras", ()),
                                 image_size=image.get("image_size", 64)) as inv:
            runs = [(m, u) for m in args.modes for u in ([None] if m == "async" else args.utd)]
            for mode, utd in runs:
                r = run(mode, policy, list(inv.addresses), args, utd)
                results.append(r)
                label = mode if utd is None else f"{mode} utd {utd:g}"
                print(f"{policy:14s} {label:12s}  collection {r['collection_s_per_episode']:7.2f} s/episode  "
                      f"training {r['training_s_per_update']:7.3f} s/update  ({r['episodes']} episodes, "
                      f"{r['updates']} updates in {r['window_s']:.0f} s)", flush=True)
    rows = speedups(results)
    for r in rows:
        print(f"{r['policy']} (sync utd {r['utd']:g}): async vs sync {r['collection']:.2f}x collection, "
              f"{r['training']:.2f}x training per update")
    out = {"args": vars(args), "machine": machine_info(), "results": results, "speedups": rows}
    os.makedirs(os.path.dirname(os.path.join(REPO, args.out)), exist_ok=True)
    with open(os.path.join(REPO, args.out), "w") as f:
        json.dump(out, f, indent=1, default=float)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
