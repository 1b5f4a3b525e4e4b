"""Where the learner's batches come from: trajectory slots (on-policy) or the replay rings (off-policy).

Cut out of the trainer (``training/trainer.py``), which runs one source per run and asks it for batches
through the prefetch thread (``produce``) and for its bookkeeping after each update (``advance``):

* ``TrajectorySource``: one slot per worker (lock-step) or the next ready slots (async) from the pool's
  ``collect``, moved to the device; logs the policy lag.
* ``ReplaySource``: [U, B] minibatches sampled from the replay rings, with the warm-up, the update-to-data
  pacing (``--utd_mode``), seeded per-batch sampling that a resumed run repeats, and optionally the device
  mirror (``training/device_replay.py``), the persistent store (``runtime/replay_store.py``) and prior
  data (RLPD, ``core/rlpd_kernels.py``).

Both turn the pool's statistics into the logged ``episode/*``, ``reward/*`` and ``perf/*`` scalars.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import Any

import numpy as np

from unilab_jax.core import rlpd_kernels as rlpd
from unilab_jax.fields import TRAJECTORY_FIELDS, replay_fields

log = logging.getLogger(__name__)


class TrajectorySource:
    """On-policy: one slot per worker (lock-step) or the next ready slots (async) per update."""

    def __init__(self, pool: Any, xp: Any, reward_terms: tuple[str, ...]):
        self._pool, self._xp, self._terms = pool, xp, reward_terms

    def produce(self, stop: threading.Event) -> tuple[dict, dict]:
        batch, info = self._pool.collect(timeout=600.0)
        t0 = time.perf_counter()
        out = {k: self._xp.from_numpy(batch[k]) for k in TRAJECTORY_FIELDS if k in batch}
        stats = _batch_stats(batch, self._terms)
        stats["scalars"].update({"perf/collect_wait_s": info["wait_s"], "perf/collect_copy_s": info["copy_s"],
                                 "perf/to_device_s": time.perf_counter() - t0})
        stats["policy_version"] = np.asarray(batch["policy_version"])
        stats["transitions"] = int(batch["reward"].size)
        return out, stats

    def advance(self, counters: dict[str, int], stats: dict) -> bool:
        lag = counters["version"] - stats["policy_version"]
        stats["scalars"].update({"perf/policy_lag_mean": float(lag.mean()), "perf/policy_lag_max": float(lag.max())})
        counters["env_steps"] += stats["transitions"]
        counters["episodes"] += stats["episodes"]
        return True  # every update publishes

    def pool_scalars(self) -> dict[str, float]:
        st = self._pool.stats()
        # the task's per-episode metrics (e.g. the rough tasks' terrain level), as the replay source logs them
        return {**_worker_scalars(st), **{f"episode/{k}": v for k, v in st["episode_metrics"].items()}}

    def checkpoint_meta(self) -> None:
        """Nothing to add to a checkpoint: slots are collected afresh after a restart."""
        return None

    def stop(self) -> None:
        """Nothing to flush."""


def with_prior(online: dict, prior: dict | None) -> dict:
    """The minibatch ``online`` with the prior rows ``prior`` composed in (RLPD's symmetric sampling); as is without."""
    return online if prior is None else rlpd.compose({k: online[k] for k in prior}, prior)


def batch_rows(cfg: Any, prior: dict[str, np.ndarray] | None) -> tuple[int, int]:
    """(online, prior) rows of each minibatch: RLPD's symmetric split with prior data, all online rows without."""
    return rlpd.symmetric_split(cfg.batch_size, cfg.prior_fraction) if prior is not None else (cfg.batch_size, 0)


def batch_layout(fields: dict[str, tuple[tuple[int, ...], Any]], cfg: Any,
                 prior: dict[str, np.ndarray] | None = None) -> dict[str, tuple]:
    """``{field: (shape, dtype)}`` of the minibatches a :class:`ReplaySource` hands the learner, from the replay rows'
    layout ``fields`` (``{field: (row shape, dtype)}``), the algorithm's config ``cfg`` and the prior data, known
    before any worker or ring exists: what the learner compiles its update for at start-up (``learner.precompile``).
    ``[U, B, ...]``, B split into online and prior rows as ``produce`` splits it (the prior's fields only, dtypes
    promoted as the concatenation promotes them). Host-drawn and device-mirror batches alike are arrays left on the
    default device (uncommitted)."""
    u, width = cfg.updates_per_call, sum(batch_rows(cfg, prior))
    if prior is None:
        return {k: ((u, width, *shape), np.dtype(dtype)) for k, (shape, dtype) in fields.items()}
    return {k: ((u, width, *fields[k][0]), np.result_type(fields[k][1], v.dtype)) for k, v in prior.items()}


class DeferredBatch:
    """A minibatch of the device mirror, finished by the thread that runs the update (``batch()``): the staged upload
    written into the mirror, then the drawn rows gathered (and the prior rows composed in). The prefetch thread
    only copies rows out of the rings and draws on the host (``DeviceReplay.stage`` / ``draw``), so it never
    waits for an update in flight."""

    def __init__(self, mirror: Any, upload: Any, draw: tuple, prior: dict | None):
        self._mirror, self._upload, self._draw, self._prior = mirror, upload, draw, prior

    def __call__(self) -> dict:
        self._mirror.write(self._upload)
        return with_prior(self._mirror.take(self._draw), self._prior)


class ReplaySource:
    """Off-policy: workers fill the replay ring on their own; the learner samples [U, B] batches,
    holding the update-to-data ratio at ``utd`` gradient steps per env step, and publishes weights
    every ``publish_every`` gradient steps.

    * Warm-up: no gradient step before the buffer holds ``max(learning_starts, batch_size)``
      transitions. While waiting, ``produce`` hands the loop an empty batch (``{}``, a no-op for the
      learner) every ``_TICK_S`` seconds, so the loop keeps logging, evaluating and checking its
      env-step budget: a run whose ``total_steps`` is smaller than ``learning_starts`` ends cleanly
      instead of blocking until the ring fills.
    * The ratio counts env steps from the moment learning starts (as FastTD3 / SB3 do): counted from
      step 0, the first call would owe ``utd * learning_starts`` gradient steps at once, a burst
      on the small initial buffer.
    * The ratio is an upper bound. With ``hold_window`` (``--utd_mode=hold``) it is also held from
      below: the pool's env-step limit follows the learner, at ``learn_start + (gradient steps + U) /
      utd + hold_window`` (never past the run's ``total_steps``, never lowered), so workers pause when
      the learner falls more than the window behind and a slow learner gets the same gradient steps per
      env step as a fast one. The limit always covers the data the next call waits for, so paused
      workers never starve the loop. During warm-up it lets the buffer fill to ``learning_starts`` plus
      the window. Without it (``free``) workers never wait for the learner, and one slower than ``utd``
      x the env rate runs below the ratio. ``perf/utd`` logs the ratio reached.
    * Batch ``k`` of the run (``k`` = the update counter) is sampled with a generator seeded by
      ``(seed, k)``, and checkpoints record the ratio's bookkeeping, so a resumed run samples and
      paces exactly as an uninterrupted one (a batch the prefetcher drew but the loop never used is
      drawn again after the restart).
    * With a device mirror (``mirror``, :class:`~unilab_jax.training.device_replay.DeviceReplay`): each call first
      copies the newly committed rows out of the rings and starts their upload, and draws the [U, B] rows (one
      seed from the same seeded generator); the batch it hands over is a :class:`DeferredBatch`, which the
      learner's thread finishes right before the update (the upload scattered in, the rows gathered on the device).
    * With a persistent store (``--replay_dir``): before sampling, the rows the workers committed
      since the last call are copied to the store (:class:`RingSpiller`, once each); minibatches mix
      the rings (``hot_fraction``) and the disk (:class:`TieredSampler`); a checkpoint first commits
      everything received so far (the store's cursor goes into its record). After ``--resume`` the
      rings start empty and the disk tier alone can start learning at once, where the bookkeeping
      left off. Without a store, a resumed run whose rings were restored (``training/ring_snapshot.py``) goes on
      likewise; one whose rings start empty warms up again and counts the ratio afresh.
    * With prior data (``prior``, from an algorithm's ``prior_dir``: RLPD), every minibatch is composed
      of online rows drawn as above and ``prior_fraction`` of rows drawn uniformly from the prior data
      (``core.rlpd_kernels.compose``; symmetric sampling at 0.5). The warm-up and the ratio count online data only.
    """

    _TICK_S = 0.25  # seconds between no-op items while the ring warms up
    _STOP_WAIT_S = 5.0  # how long stop() waits for a sample in flight
    _RNG_TAG = 0x5A4D  # keeps the sampling stream apart from other streams derived from the run seed

    def __init__(self, pool: Any, xp: Any, cfg: Any, counters: dict[str, int], seed: int, store: Any = None,
                 hot_fraction: float = 0.5, saved: dict[str, Any] | None = None, mirror: Any = None, *,
                 total_steps: int, hold_window: int | None = None, prior: dict[str, np.ndarray] | None = None):
        self._pool, self._xp, self._cfg, self._mirror = pool, xp, cfg, mirror
        # Prior data (RLPD): each minibatch is (online, prior) rows as core.rlpd_kernels.symmetric_split says.
        self._prior = prior
        self._rows = batch_rows(cfg, prior)
        self._seed = seed % 2**32
        self._steps0 = counters["env_steps"]  # env steps before this process (resume)
        self._budget = max(int(total_steps) - self._steps0, 0)  # pool env steps this process may take
        self._window, self._allowed = hold_window, 0  # ratio holding: window, pool step limit set so far
        self._updates0 = counters["updates"]  # batches used before this process: the next batch's RNG index
        saved = saved or {}
        self._learn_start: int | None = saved.get("learn_start")  # run env steps when learning started
        self._grad_steps = int(saved.get("grad_steps", 0))  # gradient steps since then (produced)
        self._since_publish = int(saved.get("since_publish", 0))
        self._produced = self._consumed = 0  # batches made / used by the loop in this process
        self._warm = self._waited = False
        self._need = max(int(cfg.learning_starts), int(cfg.batch_size))
        self._lock = threading.RLock()  # the sampling thread vs checkpoints and shutdown in the main thread
        self._stopped = False
        self._store, self._spiller, self._tiers = store, None, None
        if store is not None:
            from unilab_jax.runtime.replay_store import RingSpiller, TieredSampler

            self._spiller = RingSpiller(pool.buffer, store)
            self._tiers = TieredSampler(pool.replay_size, lambda n, rng: pool.sample(n, rng, serial_steps=0), store,
                                        hot_fraction, replay_fields(pool.spec))
        capacity = pool.num_workers * pool.buffer.capacity
        if self._need > capacity:
            raise ValueError(f"learning_starts/batch_size ({self._need}) exceed the replay capacity ({capacity} "
                             f"transitions over {pool.num_workers} workers): raise replay_capacity")
        if self._window is not None:
            self._hold(self._need + self._window)

    def _placed(self, rows: dict[str, np.ndarray], u: int, n: int) -> dict:
        """Host rows ``[u * n, ...]`` as the learner's ``[u, n, ...]`` arrays."""
        return {k: self._xp.from_numpy(v.reshape(u, n, *v.shape[1:])) for k, v in rows.items()}

    def _env_steps(self) -> int:
        return self._steps0 + self._pool.env_steps()

    def _hold(self, limit: int) -> None:
        """Raises the pool's env-step limit (pool steps) to ``limit``, capped by the run's budget."""
        limit = min(max(limit, self._allowed), self._budget)
        if limit != self._allowed:
            self._allowed = limit
            self._pool.set_step_limit(limit)

    def _sampleable(self) -> int:
        hot = self._pool.replay_size()
        return hot if self._store is None else max(hot, self._store.size)

    def _wait_tick(self) -> None:
        """One short wait for data: serial mode steps the in-process workers, process mode sleeps
        (and notices a dead worker instead of spinning forever)."""
        if self._pool.serial:
            if self._pool.pump(1) == 0:
                raise RuntimeError("serial replay workers cannot step (no weights published?)")
        else:
            self._pool._maybe_check_workers()
            time.sleep(0.002)

    def produce(self, stop: threading.Event) -> tuple[dict, dict] | None:
        cfg, pool = self._cfg, self._pool
        u, (b, b_prior) = cfg.updates_per_call, self._rows
        noop = {}, {"scalars": {}, "episodes": 0, "noop": True}
        if not self._warm:
            t_end = time.monotonic() + self._TICK_S
            while self._sampleable() < self._need:
                self._waited = True
                if stop.is_set():
                    return None
                if time.monotonic() >= t_end:
                    return noop
                if self._window is not None and pool.step_limit_reached():  # a worker's ring wrapped: go on
                    self._hold(pool.env_steps() + self._window)
                self._wait_tick()
            self._warm = True
            if self._learn_start is None or self._waited:  # (re)starting from a buffer that had to fill
                self._learn_start, self._grad_steps = self._env_steps(), 0
        if self._window is not None:  # let the workers bring this call's data, and the window beyond it
            self._hold(self._learn_start - self._steps0 + math.ceil((self._grad_steps + u) / cfg.utd) + self._window)
        # Hold the update-to-data ratio: wait for data rather than over-train on a small buffer.
        t0 = time.perf_counter()
        while self._grad_steps + u > cfg.utd * (self._env_steps() - self._learn_start):
            if stop.is_set():
                return None
            if pool.env_steps() >= self._budget:  # capped workers will not bring the data: let the loop end
                return noop
            self._wait_tick()
        t1 = time.perf_counter()
        rng = np.random.default_rng([self._seed, self._RNG_TAG, self._updates0 + self._produced])
        with self._lock:
            if self._stopped:
                return None
            scalars = {}
            if self._mirror is not None:
                pool.before_sample()
                upload, n = self._mirror.stage()
                scalars["perf/replay_upload_rows"] = float(n)
                draw = self._mirror.draw((u, b), rng)
            else:
                if self._store is None:
                    batch = pool.sample(u * b, rng)
                else:
                    pool.pump(1)  # serial mode: the env step pool.sample takes on the ring-only path
                    self._spiller.spill()
                    batch = self._tiers.sample(u, b, rng)
                out = self._placed({k: batch[k] for k in replay_fields(self._pool.spec)}, u, b)
            prior = None
            if b_prior:  # the prior data holds fields.prior_fields only: the task's others (``source``) are left out
                idx = rng.integers(0, len(self._prior["reward"]), size=u * b_prior)
                prior = self._placed({k: v[idx] for k, v in self._prior.items()}, u, b_prior)
                scalars["perf/prior_rows"] = float(b_prior)
            out = (DeferredBatch(self._mirror, upload, draw, prior) if self._mirror is not None
                   else with_prior(out, prior))
        self._grad_steps += u
        self._produced += 1
        scalars.update({"perf/utd_wait_s": t1 - t0, "perf/sample_s": time.perf_counter() - t1})
        return out, {"scalars": scalars, "episodes": 0}

    def advance(self, counters: dict[str, int], stats: dict) -> bool:
        counters["env_steps"] = self._env_steps()
        if stats.get("noop"):  # warm-up tick: no gradient step happened, nothing to publish
            counters["updates"] -= 1
            return False
        self._consumed += 1
        learned_on = max(self._env_steps() - (self._learn_start or 0), 1)
        stats["scalars"].update({"perf/utd": self._grad_steps / learned_on, "perf/utd_target": self._cfg.utd})
        self._since_publish += self._cfg.updates_per_call
        if self._since_publish >= self._cfg.publish_every:
            self._since_publish = 0
            return True
        return False

    def shortfall(self, env_steps: int) -> str | None:
        """Why this run made fewer gradient steps than its update-to-data ratio asks, or None: no update at all
        before ``learning_starts`` (the warm-up), or a learner more than 10% (and one call) below ``utd``."""
        cfg = self._cfg
        if self._learn_start is None:
            return (f"no learner update: off-policy learning starts once the replay buffer holds "
                    f"max(learning_starts={int(cfg.learning_starts)}, batch_size={int(cfg.batch_size)}) = "
                    f"{self._need:,} transitions, and the run took {env_steps:,} env steps; raise --total_steps "
                    f"or lower learning_starts (--config learning_starts=N)")
        done = self._grad_steps_used()  # a resumed run's too, when its bookkeeping went on (restored replay)
        owed = cfg.utd * max(env_steps - self._learn_start, 0)
        if done < 0.9 * owed and owed - done >= cfg.updates_per_call:
            return (f"fewer learner updates than asked: {done:,} gradient steps where utd={cfg.utd:g} asks "
                    f"{owed:,.0f} for the {env_steps - self._learn_start:,} env steps since learning started "
                    f"(the learner fell behind the workers; --utd_mode=hold keeps the ratio)")
        return None

    def _grad_steps_used(self) -> int:
        """Gradient steps since learning started, in the batches the loop has used (not those prefetched)."""
        return max(self._grad_steps - (self._produced - self._consumed) * self._cfg.updates_per_call, 0)

    def _persist(self) -> None:
        """Copies every committed ring row to the store and commits them (the rings must be open)."""
        with self._lock:
            if self._store is not None and not self._stopped:
                self._spiller.spill()
                self._store.flush()

    def checkpoint_meta(self) -> dict[str, Any]:
        """The sampling bookkeeping as of the batches the loop has used (not the one prefetched), and
        the store's cursor after committing everything received so far."""
        self._persist()
        meta: dict[str, Any] = {"learn_start": self._learn_start, "since_publish": self._since_publish,
                                "grad_steps": self._grad_steps_used()}
        if self._store is not None:
            meta.update({"store_dir": self._store.directory, "store_committed": self._store.committed,
                         "store_size": self._store.size, "spill_lost": self._spiller.lost})
        return meta

    def stop(self) -> None:
        """Final commit to the store, then no more access to the rings (the pool closes next). A
        failing commit is logged, not raised: the checkpoint that follows matters more. Waits at most
        ``_STOP_WAIT_S`` for a sample in flight (a first device-mirror call compiles), then gives up."""
        if not self._lock.acquire(timeout=self._STOP_WAIT_S):
            log.warning("replay: a sample was still running after %.0f s; stopping without the final commit",
                        self._STOP_WAIT_S)
            self._stopped = True
            return
        try:
            self._persist()
        except Exception:  # a full disk, say: still close the pool and write the checkpoint
            log.exception("replay store: the final commit failed; the last chunk is lost")
        finally:
            self._stopped = True
            self._lock.release()

    def pool_scalars(self) -> dict[str, float]:
        st = self._pool.stats()
        hot = float(st.get("replay_size", 0))
        # Replay workers wait only for the first weights and at the step limit: the pause of a held ratio.
        out = {"replay/size": hot, "perf/workers_paused_s": st["worker_wait_s"], **_worker_scalars(st)}
        out.update({f"ray/{k}": v for k, v in st.get("ray", {}).items()})  # Ray rollouts: hosts alive, lost
        if self._store is not None:
            disk = self._store.size
            # Rings and disk overlap (every ring row is written through): distinct rows ~ the larger tier.
            out.update({"replay/size": float(max(hot, disk + self._store.pending)), "replay/size_hot": hot,
                        "replay/size_disk": float(disk), "replay/disk_committed": float(self._store.committed),
                        "replay/disk_gb": self._store.disk_bytes / 1e9, "replay/spill_lost": float(self._spiller.lost)})
        if st["recent_episode_returns"].size:
            out["episode/return"] = st["episode_return_mean"]
            out["episode/length"] = st["episode_length_mean"]
            out["episode/terminated_fraction"] = st["episode_terminated_fraction"]
        out.update({f"reward/{k}": v for k, v in st["reward_terms"].items()})
        out.update({f"episode/{k}": v for k, v in st["episode_metrics"].items()})
        return out


def _worker_scalars(stats: dict[str, Any]) -> dict[str, float]:
    """Worker throughput and where worker time goes (act / task / write / wait fractions)."""
    out = {"perf/worker_env_steps_per_s": stats["env_steps_per_s"],
           "perf/worker_restarts": stats["worker_restarts"], "perf/nonfinite_rows": stats["nonfinite_rows"],
           "perf/interrupted_steps": stats["interrupted_steps"], "perf/workers_waiting": stats["workers_waiting"]}
    out.update({f"perf/worker_{k}_fraction": v for k, v in stats["worker_time_fraction"].items()})
    if stats.get("worker_policy_versions"):  # the oldest weights a worker acts with, beside the newest written
        out["perf/worker_policy_version_min"] = float(min(stats["worker_policy_versions"]))
        out["perf/published_version"] = float(stats["published_version"])
    return out


def _batch_stats(batch: dict[str, np.ndarray], reward_terms: tuple[str, ...]) -> dict[str, Any]:
    done = np.asarray(batch["terminated"], bool) | np.asarray(batch["truncated"], bool)
    scalars: dict[str, float] = {}
    if done.any():
        scalars["episode/return"] = float(np.mean(batch["episode_return"][done]))
        scalars["episode/length"] = float(np.mean(batch["episode_length"][done]))
        scalars["episode/terminated_fraction"] = float(np.mean(np.asarray(batch["terminated"], bool)[done]))
    scalars["reward/step_mean"] = float(np.mean(batch["reward"]))
    for i, name in enumerate(reward_terms):
        scalars[f"reward/{name}"] = float(np.mean(batch["reward_terms"][..., i]))
    return {"episodes": int(done.sum()), "scalars": scalars}
