"""Rollouts on several hosts through Ray: the learner's pool when ``--ray_address`` is given (replay algorithms).

Each alive Ray node with CPUs runs one :class:`~unilab_jax.runtime.host_rollouts.HostRollouts` actor, pinned
to it (``NodeAffinitySchedulingStrategy``, ``num_cpus=0``: the actor only drives the host's own worker
processes, which Ray does not schedule). The learner's node gets ``num_workers`` workers, every other node
``workers_per_host``. Inside a host the shared-memory runtime is unchanged.

Data path. The learner holds one shared-memory :class:`ReplayBuffer` with a ring per worker of every host
(worker ``j`` of host ``h`` is ring ``offset[h] + j``). A pump thread keeps one ``pull`` in flight per host;
each reply (thousands of transitions as numpy arrays, through Ray's object store) is written into those
rings in commits of M rows with the writers' protocol, so sampling, ``read_new`` (the device mirror), the
ring spiller and every learner-side consumer work as with local workers. Weights go the other way by
version: ``publish`` puts the numpy pytree into the object store once, and the pump sends its reference to
every host whose version is older (a host applies only newer versions).

Exactly-once. Each host numbers its pulls and sends, per worker, the global row index of its first row;
the pump checks both against what it has (a repeated or skipped pull, or rows before the next expected
one, raise). Rows a host's ring overwrote before they were pulled are counted (``ray_rows_overrun``), never
sent torn. So the learner holds every transition it got exactly once.

A lost host (its node died, its actor was killed, the network dropped it: any Ray error other than a Python
error in the actor) is dropped with a warning and the run goes on with the others: the rows already
received stay in its rings (sampled like a dead worker's committed rows); rows it had not shipped are lost
with it (like a dead worker's uncommitted rows); its share of the env-step budget goes to the others. A
Python error inside a host (e.g. its pool's ``WorkerDiedError``) stops the run, as locally. With no host
left the pool raises :class:`~unilab_jax.runtime.pool.WorkerDiedError`.

Env-step limit. ``set_step_limit(n)`` is over transitions received; the pump splits what is left of it evenly
over the alive hosts after every reply (a host's limit is what it has shipped plus its share), so a slow or
lost host does not strand budget.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from unilab_jax.runtime.buffers import ReplayBuffer
from unilab_jax.runtime.host_rollouts import HostRollouts
from unilab_jax.runtime.pool import WorkerDiedError, load_algo

log = logging.getLogger(__name__)


def check_address(address: str) -> None:
    """``auto`` or ``HOST:PORT``; ValueError otherwise (no connection is made)."""
    host, _, port = address.rpartition(":")
    if address != "auto" and not (host and port.isdigit() and 0 < int(port) < 65536):
        raise ValueError(f"--ray_address={address!r}: give 'auto' or HOST:PORT of the Ray head (e.g. 10.0.0.1:6379)")


class RayPool:
    """The :class:`WorkerPool` interface of the replay loop over one worker pool per Ray node.

    Args (beyond :class:`WorkerPool`'s, which go to every host's pool):
      address: ``auto`` or ``HOST:PORT`` of a running Ray cluster (``ray.init(address)``).
      workers_per_host: worker processes on each node other than the learner's (None: ``num_workers``).
      pull_rows, pull_wait_s: a host answers a pull once it has ``pull_rows`` new transitions, or after
        ``pull_wait_s`` with what it has.
      lost_host_timeout: seconds a host may leave a pull unanswered (beyond ``pull_wait_s``) before it is
        taken as lost (a hung node). None: only Ray's own failure detection.
    """

    serial = False

    def __init__(self, address: str, task_name: str, task_overrides: Mapping[str, Any] | None = None,
                 num_workers: int = 1, envs_per_worker: int = 1, seed: int = 0, algo_module: str = "",
                 weight_template: Any = None, replay_capacity: int = 0, max_env_steps: int | None = None,
                 workers_per_host: int | None = None, pull_rows: int = 4096, pull_wait_s: float = 0.05,
                 lost_host_timeout: float | None = 60.0, **pool_kwargs: Any):
        import ray

        if pool_kwargs.pop("serial", False):
            raise ValueError("Ray rollouts run worker processes; serial mode is local only")
        algo = load_algo(algo_module)
        if algo.BUFFER != "replay":
            raise ValueError(f"{algo_module}: Ray rollouts carry replay transitions (off-policy algorithms only)")
        check_address(address)
        self._ray = ray
        self._owns_ray = not ray.is_initialized()
        if self._owns_ray:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        self.envs_per_worker = int(envs_per_worker)
        self._pull = (int(pull_rows), float(pull_wait_s))
        self._lost_timeout = lost_host_timeout
        self._actors: list[Any] = []
        self.buffer = None
        try:
            self._connect(task_name, task_overrides, num_workers, envs_per_worker, seed, algo, algo_module,
                          weight_template, replay_capacity, workers_per_host, pool_kwargs)
        except BaseException:
            self.alive = [False] * len(self._actors)  # none started: kill them, close nothing
            self._teardown()
            raise
        self._limit: int | None = max_env_steps

    def _connect(self, task_name: str, task_overrides: Mapping[str, Any] | None, num_workers: int,
                 envs_per_worker: int, seed: int, algo: Any, algo_module: str, weight_template: Any,
                 replay_capacity: int, workers_per_host: int | None, pool_kwargs: dict) -> None:
        """Finds the nodes, creates the learner-side rings and one actor per node (not started yet)."""
        import ray
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        import tasks
        from unilab_jax.runtime.buffers import transition_layout

        here = ray.get_runtime_context().get_node_id()
        nodes = sorted((n for n in ray.nodes() if n["Alive"] and n["Resources"].get("CPU", 0) > 0),
                       key=lambda n: n["NodeID"] != here)  # the learner's node first
        if not nodes:
            raise RuntimeError("the Ray cluster has no alive node with CPUs")
        self.hosts = [n["NodeManagerAddress"] + (" (learner)" if n["NodeID"] == here else "") for n in nodes]
        counts = [num_workers if n["NodeID"] == here else (workers_per_host or num_workers) for n in nodes]
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(int)
        self.num_workers = int(self.offsets[-1])
        probe = tasks.make(task_name, 1, seed, dict(task_overrides or {}))
        self.spec = probe.spec
        probe.close()
        self.fields = transition_layout(self.spec, algo.extras(self.spec.action_dim))
        self.buffer = ReplayBuffer.create(self.fields, self.num_workers, envs_per_worker, replay_capacity,
                                          row_sums=pool_kwargs.get("replay_row_sums", True))
        remote = ray.remote(HostRollouts)
        for h, node in enumerate(nodes):
            strategy = NodeAffinitySchedulingStrategy(node["NodeID"], soft=False)
            self._actors.append(remote.options(num_cpus=0, max_restarts=0, scheduling_strategy=strategy).remote(
                task_name=task_name, task_overrides=task_overrides, num_workers=counts[h],
                envs_per_worker=envs_per_worker, seed=seed + 100_003 * h, algo_module=algo_module,
                weight_template=weight_template, replay_capacity=replay_capacity, **pool_kwargs))
        n_hosts = len(nodes)
        self.alive = [True] * n_hosts
        self._seq = [0] * n_hosts
        self._next = np.zeros(self.num_workers, np.int64)  # next expected global row per ring
        self._received = np.zeros(n_hosts, np.int64)  # transitions received per host
        self._host_stats: list[dict | None] = [None] * n_hosts
        self._sent_version = [-1] * n_hosts
        self._sent_limit: list[int | None] = [None] * n_hosts
        self.overrun = 0
        self.version = -1
        self._weights_ref: Any = None
        self._error: BaseException | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._t_start = time.monotonic()
        self._last_stats = (self._t_start, 0)
        self._closed = False

    # ---- lifecycle ----------------------------------------------------------------------------
    def start(self, wait: bool = True, timeout: float = 300.0, stop: Callable[[], bool] | None = None) -> RayPool:
        """Starts every host's workers (a host that fails to start counts as lost), then the pump thread."""
        from unilab_jax.runtime.ring import StopRequested

        refs = {h: a.start.remote(timeout) for h, a in enumerate(self._actors)}
        t_end = time.monotonic() + timeout
        while refs:
            ready, _ = self._ray.wait(list(refs.values()), num_returns=1, timeout=0.2)
            if stop is not None and stop():
                raise StopRequested("stop requested while the hosts were starting")
            if not ready and time.monotonic() > t_end:
                raise TimeoutError(f"Ray hosts {[self.hosts[h] for h in refs]} did not start in {timeout} s")
            for ref in ready:
                h = next(k for k, v in refs.items() if v == ref)
                del refs[h]
                self._call(h, ref)
        self._require_hosts()
        self._t_start = time.monotonic()
        self._last_stats = (self._t_start, 0)
        self._thread = threading.Thread(target=self._pump_loop, name="ray-pump", daemon=True)
        self._thread.start()
        return self

    def close(self, grace: float = 5.0) -> None:
        """Stops the pump, closes every host's pool (its workers and segments), unlinks the rings."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=grace + 5.0)
        self._teardown(grace)

    def _teardown(self, grace: float = 5.0) -> None:
        """Closes the alive hosts' pools, kills every actor, unlinks the rings, disconnects (if it connected)."""
        closing = [a.close.remote() for h, a in enumerate(self._actors) if self.alive[h]]
        if closing:
            self._ray.wait(closing, num_returns=len(closing), timeout=grace + 5.0)
        for a in self._actors:
            self._kill(a)
        if self.buffer is not None:
            self.buffer.close()
        if self._owns_ray:
            self._ray.shutdown()

    @property
    def closed(self) -> bool:
        return self._closed

    def _call(self, h: int, ref: Any) -> Any:
        """``ray.get(ref)`` of host ``h``'s call; a lost host is marked (None), a Python error raised."""
        try:
            return self._ray.get(ref)
        except self._ray.exceptions.RayTaskError:
            raise
        except self._ray.exceptions.RayError as e:
            self._lose(h, f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}")
            return None

    def _lose(self, h: int, why: str) -> None:
        if self.alive[h]:
            self.alive[h] = False
            log.warning("Ray host %s lost (%s); %d received transitions kept, the run goes on with %d host(s)",
                        self.hosts[h], why, self._received[h], sum(self.alive))
            self._kill(self._actors[h])

    def _kill(self, actor: Any) -> None:
        with contextlib.suppress(Exception):  # already gone with its node
            self._ray.kill(actor)

    def _require_hosts(self) -> None:
        if not any(self.alive):
            raise WorkerDiedError(f"every Ray host is lost ({', '.join(self.hosts)})")

    # ---- the pump thread ----------------------------------------------------------------------
    def _pump_loop(self) -> None:
        pending: dict[int, tuple[Any, float]] = {}
        try:
            while not self._stop.is_set():
                self._send_limits()
                self._send_weights()
                for h, a in enumerate(self._actors):
                    if self.alive[h] and h not in pending:
                        pending[h] = (a.pull.remote(*self._pull), time.monotonic())
                refs = [r for r, _ in pending.values()]
                ready, _ = self._ray.wait(refs, num_returns=1, timeout=0.1) if refs else ([], [])
                for h, (ref, t0) in list(pending.items()):
                    if ref in ready:
                        del pending[h]
                        reply = self._call(h, ref)
                        if reply is not None:
                            self._store(h, reply)
                    elif self._lost_timeout is not None and time.monotonic() - t0 > self._pull[1] + self._lost_timeout:
                        del pending[h]
                        self._lose(h, f"no answer to a pull for {self._lost_timeout:.0f} s")
                self._require_hosts()
        except BaseException as e:  # surfaced by the learner's next call
            self._error = e

    def _send_weights(self) -> None:
        version, ref = self.version, self._weights_ref
        if ref is None:
            return
        for h, a in enumerate(self._actors):
            if self.alive[h] and self._sent_version[h] < version:
                a.publish.remote(ref, version)
                self._sent_version[h] = version

    def _send_limits(self) -> None:
        if self._limit is None:
            return
        alive = [h for h in range(len(self._actors)) if self.alive[h]]
        share = math.ceil(max(self._limit - int(self._received.sum()), 0) / max(len(alive), 1))
        for h in alive:
            limit = int(self._received[h]) + share
            if limit != self._sent_limit[h]:
                self._actors[h].allow.remote(limit)
                self._sent_limit[h] = limit

    def _store(self, h: int, reply: dict) -> None:
        """Writes a host's pulled rows into its rings, checking that nothing repeats or goes missing."""
        if reply["seq"] != self._seq[h] + 1:
            raise RuntimeError(f"Ray host {self.hosts[h]}: pull {reply['seq']} after pull {self._seq[h]}")
        self._seq[h] = reply["seq"]
        m, rows, o = self.envs_per_worker, reply["rows"], 0
        for j, (start, n) in enumerate(zip(reply["start"], reply["n"])):
            ring = int(self.offsets[h]) + j
            if start < self._next[ring] or n % m or start % m:
                raise RuntimeError(f"Ray host {self.hosts[h]} worker {j}: rows from {start} ({n}) after "
                                   f"{self._next[ring]} received")
            self.overrun += int(start - self._next[ring])
            for c in range(int(n) // m):
                _, views = self.buffer.rows(ring)
                for k, v in views.items():
                    v[...] = rows[k][o + c * m : o + (c + 1) * m]
                self.buffer.commit(ring)
            o += int(n)
            self._next[ring] = start + n
            self._received[h] += int(n)
        self._host_stats[h] = reply["stats"]

    # ---- the WorkerPool interface of the replay loop ------------------------------------------
    def _maybe_check_workers(self) -> None:
        """Raises what the pump thread met (a host's Python error, every host lost)."""
        if self._error is not None:
            raise self._error
        if self._thread is not None and not self._thread.is_alive() and not self._stop.is_set():
            raise RuntimeError("the Ray pump thread stopped")

    def before_sample(self, serial_steps: int = 1) -> None:
        self._maybe_check_workers()

    def pump(self, steps: int = 1) -> int:
        return 0

    def publish(self, weights: Any, version: int) -> None:
        self._weights_ref = self._ray.put(weights)
        self.version = int(version)

    def set_step_limit(self, max_env_steps: int | None) -> None:
        self._limit = None if max_env_steps is None else max(int(max_env_steps), 0)

    def step_limit_reached(self) -> bool:
        return self._limit is not None and self._limit <= self.env_steps()

    def env_steps(self) -> int:
        return int(self._received.sum())

    def replay_size(self) -> int:
        return self.buffer.size()

    def sample(self, batch_size: int, rng: np.random.Generator, serial_steps: int = 1) -> dict[str, np.ndarray]:
        self._maybe_check_workers()
        return self.buffer.sample(batch_size, rng)

    def stats(self) -> dict[str, Any]:
        """The WorkerPool statistics the trainer logs, summed over the hosts' latest pulls, plus ``ray``."""
        now, steps = time.monotonic(), self.env_steps()
        prev_t, prev_steps = self._last_stats
        self._last_stats = (now, steps)
        got = [s for s in self._host_stats if s is not None]
        returns = np.concatenate([s["recent_episode_returns"] for s in got]) if got else np.zeros(0)
        lengths = np.concatenate([s["recent_episode_lengths"] for s in got]) if got else np.zeros(0)
        fractions = [s["worker_time_fraction"] for s in got]
        ended = [(s["episode_terminated_fraction"], s["recent_episode_returns"].size) for s in got
                 if s["recent_episode_returns"].size]
        per_episode = {k: [s["episode_metrics"][k] for s in got if k in s["episode_metrics"]]
                       for k in self.spec.episode_metrics}
        return {
            "env_steps": steps, "env_steps_per_s": (steps - prev_steps) / max(now - prev_t, 1e-9),
            "env_steps_per_s_total": steps / max(now - self._t_start, 1e-9),
            "episodes": sum(int(s["episodes"]) for s in got),
            "episode_metrics": {k: float(np.mean(v)) for k, v in per_episode.items() if v},
            "episode_return_mean": float(returns.mean()) if returns.size else float("nan"),
            "episode_length_mean": float(lengths.mean()) if lengths.size else float("nan"),
            "episode_terminated_fraction": sum(f * n for f, n in ended) / sum(n for _, n in ended) if ended
            else float("nan"),
            "recent_episode_returns": returns, "recent_episode_lengths": lengths,
            "reward_terms": {k: float(np.mean([s["reward_terms"][k] for s in got])) for k in self.spec.reward_terms}
            if got else {},
            **{k: sum(s[k] for s in got) for k in ("worker_restarts", "nonfinite_rows", "interrupted_steps",
                                                    "workers_waiting", "worker_wait_s")},
            "worker_time_fraction": {k: float(np.mean([f[k] for f in fractions])) for k in fractions[0]}
            if fractions else {},
            "replay_size": self.buffer.size(), "published_version": self.version,
            "ray": {"hosts_alive": float(sum(self.alive)), "hosts_lost": float(len(self.alive) - sum(self.alive)),
                    "rows_overrun": float(self.overrun)},
        }
