"""GPU-resident training on MJX: policy, physics and learner on the accelerator, the baseline of issue #7.

The way MuJoCo Playground (brax) or IsaacLab users train, built from this project's own pieces so that
only the placement of the simulation differs from the heterogeneous runtime:

* the environment is the MJX variant of the CPU task (``tasks/mjx_go1.py`` for Go1, ``tasks/mjx_walking.py``
  for Go2 / G1, ``tasks/mjx_rough.py`` for the three on rough terrain: same model, observation, reward, resets
  and domain randomisation, float32); episode metrics (the rough tasks' terrain levels) are logged as
  ``episode/<name>`` over the episodes that ended, as the CPU trainer logs them;
* the algorithms are the same modules: ``act`` (shim-written, here on jax arrays), the networks, and
  the jitted learner updates of ``algos/ppo/learner_jax.py`` and ``algos/offpolicy/learner_jax.py`` (their ``_update``
  is traced into the training step below);
* **PPO**: one ``jax.jit`` call runs ``iterations_per_call`` iterations, each a ``lax.scan`` of
  ``horizon`` control steps of all ``num_envs`` envs (policy + ``nsub`` MJX substeps + auto-reset)
  followed by the PPO update on the ``[horizon, num_envs]`` batch (GAE, epochs x minibatches);
* **SAC family** (FastSAC): a replay ring of ``replay_capacity`` transitions in device memory; each
  iteration steps all envs ``env_steps_per_iter`` times, appends the transitions, and (once
  ``learning_starts`` transitions are in) runs ``updates_per_iter`` learner calls of
  ``updates_per_call`` gradient steps on uniformly sampled ``[U, batch_size]`` batches, so that
  gradient steps per transition match ``config.utd`` as on the runtime;
* evaluation: the deterministic policy on a separate MJX env of ``eval_envs`` envs (same task
  config: noise and domain randomisation on, as the CPU trainer's evaluation), one episode each,
  return summed until the episode's first end. The policy and the env step are two jitted functions
  driven by a Python loop (all arrays stay on the device), so every algorithm shares the compiled
  env step; they compile in a background thread while the first training call compiles.
  Evaluations block training here (the runtime evaluates in a background thread), so
  besides ``eval/wall_s`` (from process start, compilation and evaluations included, as brax counts)
  each evaluation logs ``eval/train_wall_s``: the same clock minus the time spent in evaluations.

Logs through ``unilab_jax.metrics`` (TensorBoard + ``metrics.jsonl``) with the CPU trainer's names
(``loss/*``, ``episode/return``, ``reward/<term>``, ``perf/env_steps_per_s``, ``time/wall_s``, ``eval/*``).
No checkpoints: runs are benchmark-sized.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import json
import math
import os
import threading
import time
from concurrent import futures
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from unilab_jax import algos
from unilab_jax.fields import REPLAY_FIELDS, TRAJECTORY_FIELDS
from unilab_jax.metrics import WALKING, MetricLogger
from unilab_jax.runtime.ring import StopRequested
from unilab_jax.training import compile_cache
from unilab_jax.training.threads import LearnerThread, stop_on_signals, wait_result

# task name -> module with ``make(config, num_envs)`` (the walking and rough modules pick the task from the config's
# type); the rough module's ``make`` also takes ``evaluation`` (envs frozen on the evaluation cells)
MJX_TASKS = {"go1_joystick_flat": "tasks.mjx_go1", "go2_joystick_flat": "tasks.mjx_walking",
             "g1_walk_flat": "tasks.mjx_walking", "go1_joystick_rough": "tasks.mjx_rough",
             "go2_joystick_rough": "tasks.mjx_rough", "g1_walk_rough": "tasks.mjx_rough"}
FROZEN_FOR_EVALUATION = ("tasks.mjx_rough",)  # modules whose evaluation envs differ from the training envs


@dataclasses.dataclass(frozen=True)
class MjxRunConfig:
    """Everything about an MJX run that is not an algorithm or task hyperparameter."""

    algo: str
    task: str
    num_envs: int = 1024
    total_steps: int = 1_000_000
    seed: int = 0
    logdir: str = "runs/mjx"
    eval_every: int = 0  # env steps between evaluations (0: only at the end)
    eval_envs: int = 16
    max_seconds: float = 0.0  # stop (without a final evaluation) once this much wall time has passed; 0: no limit
    iterations_per_call: int = 1  # training iterations per jitted call (one logged row per call)
    compilation_cache: str = "auto"  # RunConfig.compilation_cache (training/compile_cache.py)


# --------------------------------------------------------------------------------------------------
# Environments
# --------------------------------------------------------------------------------------------------
class EnvFns(NamedTuple):
    env: Any
    reset: Any  # jitted env.reset
    step: Any  # jitted env.step


_ENVS: dict[tuple, EnvFns] = {}


def make_env(task: str, num_envs: int, overrides: dict[str, Any] | None = None,
             compiler_options: dict[str, Any] | None = None, evaluation: bool = False) -> EnvFns:
    """The MJX env of ``task`` with jitted reset/step, cached per (task, overrides, num_envs, compiler
    options, evaluation) so every user in the process shares one compilation; ``evaluation``: the env the
    evaluations run (the rough tasks' frozen on their evaluation cells; the others' is the training env)."""
    import tasks
    from unilab_jax.config import apply_overrides

    if task not in MJX_TASKS:
        raise ValueError(f"task {task!r} has no MJX variant; MJX tasks: {sorted(MJX_TASKS)}")
    config = apply_overrides(tasks.default_config(task), overrides or {})
    frozen = evaluation and MJX_TASKS[task] in FROZEN_FOR_EVALUATION
    key = (task, config, int(num_envs), tuple(sorted((compiler_options or {}).items())), frozen)
    if key not in _ENVS:
        module = importlib.import_module(MJX_TASKS[task])
        env = module.make(config, num_envs, evaluation=True) if frozen else module.make(config, num_envs)
        _ENVS[key] = EnvFns(env, jax.jit(env.reset, compiler_options=compiler_options),
                            jax.jit(env.step, compiler_options=compiler_options))
    return _ENVS[key]


def evaluate(env: EnvFns, act: Any, weights: Any, key: jax.Array) -> dict[str, float]:
    """One deterministic episode in each env: mean/std return summed until each env's first end, mean
    length, fall rate (terminated, not truncated), and the walking metric over the same episodes
    (``tasks.walking_metric.WalkingTracker``'s tracking and yaw-rate errors, ``eval/walking`` by
    ``metrics.WALKING``); on the rough tasks also their ``evaluation_numbers`` (per terrain type, the
    rough-terrain criterion ``eval/rough_terrain_walking``). ``act(weights, obs) -> action`` is jitted."""
    state = env.reset(key)
    n = env.env.num_envs
    ret, length = jnp.zeros(n), jnp.zeros(n, jnp.int32)
    alive, fell = jnp.ones(n, bool), jnp.zeros(n, bool)
    errors = jnp.zeros((n, 3))  # per env: tracking error sum, yaw-rate error sum, evaluated steps
    for t in range(env.env.spec.episode_length):
        command = state.info["command"]
        state, out = env.step(state, act(weights, state.obs))
        ret, length, alive, fell, errors = _accumulate(ret, length, alive, fell, errors, out.reward, out.terminated,
                                                       out.truncated, command, state, env.env.base_velocity)
        if t % 100 == 99 and not bool(jnp.any(alive)):
            break
    ret, per_env, fell = np.asarray(ret), np.asarray(errors, np.float64), np.asarray(fell)
    errors = per_env.sum(axis=0)
    result = {"eval/return": float(ret.mean()), "eval/return_std": float(ret.std()),
              "eval/episode_length": float(np.asarray(length).mean()), "eval/fall_rate": float(fell.mean()),
              "eval/tracking_error": float(errors[0] / errors[2]) if errors[2] else math.nan,
              "eval/yaw_rate_error": float(errors[1] / errors[2]) if errors[2] else math.nan}
    result["eval/walking"] = float(WALKING.met(result, prefix="eval/"))
    if hasattr(env.env, "evaluation_numbers"):
        numbers = env.env.evaluation_numbers(per_env[:, :2], per_env[:, 2], fell, state.extra)
        result.update({f"eval/{k}": v for k, v in numbers.items()})
    return result


@functools.partial(jax.jit, static_argnums=10)
def _accumulate(ret, length, alive, fell, errors, reward, terminated, truncated, command, state, base_velocity):
    """One step of ``evaluate``'s sums (``errors [M, 3]`` per env); a step's velocity error (``base_velocity(state)``
    against the command in force during the step) counts while its env is in its first episode and did not end on
    that step, as in ``WalkingTracker``."""
    ended = terminated | truncated
    velocity = base_velocity(state)
    ok = (alive & ~ended).astype(jnp.float32)
    err = jnp.stack([jnp.linalg.norm(command[:, :2] - velocity[:, :2], axis=1), jnp.abs(command[:, 2] - velocity[:, 2]),
                     jnp.ones_like(ok)], axis=1)
    errors = errors + ok[:, None] * err
    ret = ret + jnp.where(alive, reward, 0.0)
    length = length + alive.astype(jnp.int32)
    fell = fell | (alive & terminated)
    return ret, length, alive & ~ended, fell, errors


def _episode_stats(traj_return: jax.Array, traj_length: jax.Array, terminated: jax.Array, truncated: jax.Array,
                   reward: jax.Array, terms: dict, extras: dict) -> dict:
    """Sums for logging over a [T, M] stretch (divided on the host): finished episodes' return/length and
    episode metrics (``MjxStepOut.extras``)."""
    ended = (terminated | truncated).astype(jnp.float32)
    return {"episodes": jnp.sum(ended), "return_sum": jnp.sum(traj_return * ended),
            "length_sum": jnp.sum(traj_length * ended), "terminated": jnp.sum(terminated.astype(jnp.float32)),
            "reward_sum": jnp.sum(reward), "steps": jnp.asarray(reward.size, jnp.float32),
            **{f"term/{k}": jnp.sum(v) for k, v in terms.items()},
            **{f"extra/{k}": jnp.sum(v * ended) for k, v in extras.items()}}


def _add(a: dict, b: dict) -> dict:
    return jax.tree_util.tree_map(jnp.add, a, b)


# --------------------------------------------------------------------------------------------------
# The runner shared by both algorithm families
# --------------------------------------------------------------------------------------------------
class MjxTrainer:
    """``train() -> summary``: the host loop around a jitted ``_call(carry) -> (carry, metrics, stats)``.

    ``compiler_options`` go to every ``jax.jit`` here (``{"xla_backend_optimization_level": 0}`` cuts
    XLA's CPU compile time by about a third, for tests).
    """

    def __init__(self, run: MjxRunConfig, algo_module: Any, algo_config: Any, task_overrides: dict[str, Any],
                 start_time: float | None = None, compiler_options: dict[str, Any] | None = None):
        self.t0 = time.time() if start_time is None else start_time
        compile_cache.configure(run.compilation_cache, "jax")
        self.run, self.algo, self.config, self.task_overrides = run, algo_module, algo_config, dict(task_overrides)
        self.envs = make_env(run.task, run.num_envs, task_overrides, compiler_options)
        self.eval_env = make_env(run.task, run.eval_envs, task_overrides, compiler_options, evaluation=True)
        self.spec = self.envs.env.spec
        self.learner = algos.make_learner(algo_module, "jax", algo_config, self.spec)
        self.logger = MetricLogger(run.logdir)
        self._stop = threading.Event()
        zeros = jnp.zeros((run.eval_envs, self.spec.action_dim), jnp.float32)
        self._eval_act = jax.jit(lambda w, obs: algo_module.act(w, obs, zeros, True)[0],
                                 compiler_options=compiler_options)
        self._call = jax.jit(self._iterations, donate_argnums=0, compiler_options=compiler_options)

    # -- algorithm hooks ---------------------------------------------------------------------------
    def init_carry(self, key: jax.Array) -> Any:
        raise NotImplementedError

    def steps_per_iteration(self) -> int:
        raise NotImplementedError

    def iteration(self, carry: Any) -> tuple[Any, dict, dict]:
        raise NotImplementedError

    def weights(self, carry: Any) -> Any:
        raise NotImplementedError

    # -- the loop ------------------------------------------------------------------------------------
    def _iterations(self, carry: Any) -> tuple[Any, dict, dict]:
        def body(c, _):
            c, metrics, stats = self.iteration(c)
            return c, (metrics, stats)

        carry, (metrics, stats) = jax.lax.scan(body, carry, None, length=self.run.iterations_per_call)
        return carry, jax.tree_util.tree_map(jnp.mean, metrics), jax.tree_util.tree_map(jnp.sum, stats)

    def _call_and_scalars(self, carry: Any) -> tuple[Any, dict[str, float]]:
        carry, metrics, stats = self._call(carry)
        return carry, self._scalars(metrics, stats)  # float() waits for the call

    def _scalars(self, metrics: dict, stats: dict) -> dict[str, float]:
        out = {f"loss/{k}": float(v) for k, v in metrics.items()}
        s = {k: float(v) for k, v in stats.items()}
        if s["episodes"] > 0:
            out.update({"episode/return": s["return_sum"] / s["episodes"],
                        "episode/length": s["length_sum"] / s["episodes"],
                        "episode/terminated_fraction": s["terminated"] / s["episodes"]})
            out.update({f"episode/{k[6:]}": v / s["episodes"] for k, v in s.items() if k.startswith("extra/")})
        out["reward/step_mean"] = s["reward_sum"] / s["steps"]
        out.update({f"reward/{k[5:]}": v / s["steps"] for k, v in s.items() if k.startswith("term/")})
        return out

    def _warm_evaluation(self, weights: Any) -> futures.Future:
        """Compiles the evaluation (env reset/step, policy) in a background thread while the training call
        compiles, so the first evaluation does not stall training for a second compilation."""

        def run() -> None:
            state = self.eval_env.reset(jax.random.PRNGKey(0))
            state, out = self.eval_env.step(state, self._eval_act(weights, state.obs))
            z = jnp.zeros(self.run.eval_envs)
            errors = jnp.zeros((self.run.eval_envs, 3))
            jax.block_until_ready(_accumulate(z, z.astype(jnp.int32), z > 0, z > 0, errors, out.reward,
                                              out.terminated, out.truncated, state.info["command"], state,
                                              self.eval_env.env.base_velocity))

        thread = LearnerThread("jax", name="warm-eval")
        future = thread.submit(run)
        thread.close()  # the thread ends once the compile is done
        return future

    def _evaluate(self, carry: Any, env_steps: int, evals: int, eval_time: float) -> float:
        """Runs and logs one evaluation; returns the seconds it took."""
        wait_result(self._warm, self._stop)
        t = time.time()
        result = evaluate(self.eval_env, self._eval_act, self.weights(carry),
                          jax.random.PRNGKey(10_000 + self.run.seed * 1000 + evals))
        done = time.time()
        result.update({"eval/wall_s": t - self.t0, "eval/train_wall_s": t - self.t0 - eval_time,
                       "eval/done_wall_s": done - self.t0})
        self.logger.log(env_steps, result)
        self.last_eval = result
        return done - t

    def train(self) -> dict[str, Any]:
        run = self.run
        self.last_eval: dict[str, float] = {}
        restore_signals = stop_on_signals(self._stop)
        learner = LearnerThread("jax")
        carry = self.init_carry(jax.random.PRNGKey(run.seed))
        # A copy: the training call donates the carry's buffers.
        self._warm = self._warm_evaluation(jax.tree_util.tree_map(jnp.copy, self.weights(carry)))
        per_call = self.steps_per_iteration() * run.iterations_per_call
        env_steps, calls, evals, eval_time = 0, 0, 0, 0.0
        next_eval = run.eval_every if run.eval_every else None
        evaluated_at, reason = -1, "total_steps"
        t_last = time.time()
        try:
            while env_steps < run.total_steps:
                if self._stop.is_set():
                    reason = "signal"
                    break
                if run.max_seconds and time.time() - self.t0 >= run.max_seconds:
                    reason = "max_seconds"
                    break
                carry, scalars = learner.call(self._stop, self._call_and_scalars, carry)
                now = time.time()
                env_steps += per_call
                calls += 1
                scalars.update({"perf/env_steps_per_s": per_call / max(now - t_last, 1e-9),
                                "perf/call_s": now - t_last, "time/wall_s": now - self.t0})
                if calls == 1:
                    scalars["perf/first_call_s"] = now - t_last  # includes compilation
                self.logger.log(env_steps, scalars)
                t_last = now
                if next_eval is not None and env_steps >= next_eval:
                    eval_time += self._evaluate(carry, env_steps, evals, eval_time)
                    evals += 1
                    evaluated_at = env_steps
                    next_eval += run.eval_every
                    t_last = time.time()
            if reason == "total_steps" and evaluated_at != env_steps:
                self._evaluate(carry, env_steps, evals, eval_time)
            self.final_carry = carry  # the training state, env states (and replay ring) at the end
        except StopRequested:  # a signal during a call (the first one compiles): not waited for
            reason = "signal"
        finally:
            restore_signals()
            learner.close()
            if not self._stop.is_set():
                futures.wait([self._warm])  # never leave a compiling thread behind at interpreter exit
            self.logger.close()
        summary = {"env_steps": env_steps, "calls": calls, "wall_s": time.time() - self.t0,
                   "eval_s": eval_time, "stopped_by": reason, "logdir": os.path.abspath(run.logdir),
                   "devices": [str(d) for d in jax.devices()], **self.last_eval}
        with open(os.path.join(run.logdir, "summary.json"), "w") as f:
            json.dump(summary, f, indent=2)
        return summary


# --------------------------------------------------------------------------------------------------
# PPO
# --------------------------------------------------------------------------------------------------
class PPOMjxTrainer(MjxTrainer):
    """PPO (``algos/ppo``) with rollouts of ``config.horizon`` steps of ``num_envs`` MJX envs."""

    def init_carry(self, key: jax.Array) -> tuple:
        k_learner, k_env, k_roll = jax.random.split(key, 3)
        return self.learner.init(k_learner), self.envs.reset(k_env), k_roll

    def steps_per_iteration(self) -> int:
        return self.config.horizon * self.run.num_envs

    def weights(self, carry: tuple) -> Any:
        return self.learner.weights(carry[0])

    def iteration(self, carry: tuple) -> tuple[tuple, dict, dict]:
        train_state, env_state, key = carry
        weights = self.learner.weights(train_state)
        env, algo, a_dim = self.envs.env, self.algo, self.spec.action_dim

        def step(c, _):
            es, k = c
            k, k_noise = jax.random.split(k)
            noise = jax.random.normal(k_noise, (es.obs.shape[0], a_dim), jnp.float32)
            action, extras = algo.act(weights, es.obs, noise)
            es2, out = env.step(es, action)
            tr = {"obs": es.obs, "critic_obs": es.critic_obs, "next_critic_obs": out.next_critic_obs,
                  "action": action, "reward": out.reward, "terminated": out.terminated, "truncated": out.truncated,
                  "episode_return": out.episode_return, "episode_length": out.episode_length,
                  "terms": out.reward_terms, "episode_metrics": out.extras, **extras}
            return (es2, k), tr

        (env_state, key), traj = jax.lax.scan(step, (env_state, key), None, length=self.config.horizon)
        train_state, metrics = self.learner._update(train_state, {k: traj[k] for k in TRAJECTORY_FIELDS})
        stats = _episode_stats(traj["episode_return"], traj["episode_length"], traj["terminated"], traj["truncated"],
                               traj["reward"], traj["terms"], traj["episode_metrics"])
        return (train_state, env_state, key), metrics, stats


# --------------------------------------------------------------------------------------------------
# SAC family (FastSAC, SAC, FlashSAC): replay ring in device memory
# --------------------------------------------------------------------------------------------------
class Replay(NamedTuple):
    data: dict  # field -> [capacity, ...]
    ptr: jax.Array  # next write row (int32)
    size: jax.Array  # rows filled (int32)


class OffPolicyMjxTrainer(MjxTrainer):
    """SAC-family learner (``SACFamilyLearner``) fed from a device-resident replay ring."""

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        cfg, m = self.config, self.run.num_envs
        grad_per_env_step = cfg.utd * m  # gradient steps per vectorised env step
        if grad_per_env_step >= cfg.updates_per_call:
            self.env_steps_per_iter, self.updates_per_iter = 1, round(grad_per_env_step / cfg.updates_per_call)
        else:
            self.env_steps_per_iter, self.updates_per_iter = round(cfg.updates_per_call / grad_per_env_step), 1
        rows = max(cfg.replay_capacity // m, self.env_steps_per_iter)
        self.capacity = rows * m
        self.learning_starts = max(cfg.learning_starts, cfg.batch_size)

    def steps_per_iteration(self) -> int:
        return self.env_steps_per_iter * self.run.num_envs

    def weights(self, carry: tuple) -> Any:
        return self.learner.weights(carry[0])

    def init_carry(self, key: jax.Array) -> tuple:
        k_learner, k_env, k_roll = jax.random.split(key, 3)
        s = self.spec
        dims = {"obs": (s.obs_dim,), "critic_obs": (s.critic_obs_dim,), "action": (s.action_dim,), "reward": (),
                "next_obs": (s.obs_dim,), "next_critic_obs": (s.critic_obs_dim,), "terminated": (), "truncated": ()}
        data = {k: jnp.zeros((self.capacity, *dims[k]), jnp.float32) for k in REPLAY_FIELDS}
        replay = Replay(data, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))
        return self.learner.init(k_learner), self.envs.reset(k_env), replay, k_roll

    def iteration(self, carry: tuple) -> tuple[tuple, dict, dict]:
        train_state, env_state, replay, key = carry
        cfg, env, algo, m = self.config, self.envs.env, self.algo, self.run.num_envs
        weights = self.learner.weights(train_state)

        def env_step(c, _):
            es, rp, k = c
            k, k_noise = jax.random.split(k)
            noise = jax.random.normal(k_noise, (m, self.spec.action_dim), jnp.float32)
            action, _ = algo.act(weights, es.obs, noise)
            es2, out = env.step(es, action)
            row = {"obs": es.obs, "critic_obs": es.critic_obs, "action": action, "reward": out.reward,
                   "next_obs": out.next_obs, "next_critic_obs": out.next_critic_obs,
                   "terminated": out.terminated.astype(jnp.float32), "truncated": out.truncated.astype(jnp.float32)}
            data = {f: jax.lax.dynamic_update_slice_in_dim(rp.data[f], row[f].astype(jnp.float32), rp.ptr, axis=0)
                    for f in REPLAY_FIELDS}
            rp = Replay(data, (rp.ptr + m) % self.capacity, jnp.minimum(rp.size + m, self.capacity))
            st = _episode_stats(out.episode_return, out.episode_length, out.terminated, out.truncated, out.reward,
                                out.reward_terms, out.extras)
            return (es2, rp, k), st

        (env_state, replay, key), stats = jax.lax.scan(env_step, (env_state, replay, key), None,
                                                       length=self.env_steps_per_iter)
        stats = jax.tree_util.tree_map(jnp.sum, stats)

        def sample(k):
            idx = jax.random.randint(k, (cfg.updates_per_call, cfg.batch_size), 0, replay.size)
            return {f: replay.data[f][idx] for f in REPLAY_FIELDS}

        def learn(c):
            ts, k = c

            def one(c2, _):
                ts2, k2 = c2
                k2, k_batch = jax.random.split(k2)
                ts2, metrics = self.learner._update(ts2, sample(k_batch))
                return (ts2, k2), metrics

            (ts, k), metrics = jax.lax.scan(one, (ts, k), None, length=self.updates_per_iter)
            return ts, k, jax.tree_util.tree_map(jnp.mean, metrics)

        metric_shapes = jax.eval_shape(lambda c: learn(c)[2], (train_state, key))
        skip = lambda c: (c[0], c[1], jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), metric_shapes))
        train_state, key, metrics = jax.lax.cond(replay.size >= self.learning_starts, learn, skip, (train_state, key))
        stats["grad_steps"] = jnp.where(replay.size >= self.learning_starts,
                                        float(self.updates_per_iter * cfg.updates_per_call), 0.0)
        return (train_state, env_state, replay, key), metrics, stats

    def _scalars(self, metrics: dict, stats: dict) -> dict[str, float]:
        grad_steps = float(stats.pop("grad_steps"))
        out = super()._scalars(metrics, stats) if grad_steps > 0 else super()._scalars({}, stats)
        out["perf/grad_steps"] = grad_steps
        out["perf/utd"] = grad_steps / max(float(stats["steps"]), 1.0)
        return out


def make_trainer(run: MjxRunConfig, algo_module: Any, algo_config: Any, task_overrides: dict[str, Any],
                 start_time: float | None = None, compiler_options: dict[str, Any] | None = None) -> MjxTrainer:
    """The MJX trainer of ``algo_module``'s buffer kind (trajectory: PPO; replay: the SAC family)."""
    if algo_module.BUFFER == "trajectory" and algo_module.SYNC == "lockstep":
        cls = PPOMjxTrainer
    elif algo_module.BUFFER == "replay" and algos.info(algo_module).update == "sac":
        cls = OffPolicyMjxTrainer
    else:
        raise ValueError(f"no MJX trainer for algorithm {algo_module.__name__} (PPO and the SAC family have one)")
    if math.prod((run.num_envs, run.eval_envs, run.iterations_per_call)) <= 0:
        raise ValueError("num_envs, eval_envs and iterations_per_call must be positive")
    return cls(run, algo_module, algo_config, task_overrides, start_time, compiler_options)
