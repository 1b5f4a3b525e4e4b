"""HG-DAgger (Kelly et al. 2019, "HG-DAgger: Interactive Imitation Learning with Human Experts") on robot tasks.

    summary = HGDagger(task, HGDaggerConfig(...), seed=0, logdir="runs/hg").run()

``task`` is a robot task (``tasks/robot.py``; in-process robots or robots behind servers) whose operator
channel the loop switches per phase:

1. demonstrations: the operator (the scripted expert) drives ``demo_episodes`` whole episodes
   (``always``); a behaviour-cloned novice is fitted on them (``algos/imitation``, ``bc``: a budget of
   gradient steps; 24 demonstrations give a novice of about 60% success on pick-and-place);
2. each round: the novice drives ``episodes_per_round`` episodes with the operator gating (``gate``:
   it takes over when the novice is unsafe, drops the cube or stalls, and hands back after a segment);
   only the operator's transitions (``source == operator``) join the dataset (``intervention_weight``
   copies of each; 1: every row weighted alike, as the paper's aggregate); the novice is refitted on the
   whole aggregate (``warm_start``: fine-tuned for ``refit_steps`` from the previous round's novice, so what
   it learnt carries over; else retrained from fresh parameters); ``keep_best`` drops a refit whose
   evaluation falls below the kept novice's (its data stay), so the next round starts from the kept one;
3. after the initial fit and every round the novice is evaluated alone (``off``) for ``eval_episodes``.

The novice acts deterministically on the task's critic observation (proprioception, identity, the
object state: state observations; the actor observation holds no object state) without its last column,
the episode time, unless ``novice_time``: the operator's segments come late in episodes, and a novice that
reads the time learns from them what to do late rather than where (with it, success fell as rounds added
data: 0.88 -> 0.55 on seed 3; without, 0.48 -> 0.95 over four rounds).
``max_env_steps`` caps the robot steps of the whole run (demonstrations, rounds and evaluations): a phase
stops when it is reached, and the run ends after that phase's fit and evaluation.

Logged per phase (``metrics.jsonl`` / TensorBoard, step = robot steps so far): ``eval/success_rate``,
``eval/return``, ``hgdagger/dataset_rows``, ``hgdagger/operator_rows`` (added this round),
``hgdagger/intervention_rate`` and ``hgdagger/interventions`` (per episode of the round),
``hgdagger/round_success_rate`` (the gated episodes' successes, with the operator's help),
``hgdagger/bc_loss``, ``hgdagger/kept`` (1: this round's refit is the novice now),
``hgdagger/kept_success_rate`` (the kept novice's evaluation), ``hgdagger/eval_steps`` (the evaluation's
robot steps), ``hgdagger/wall_s``.

A separate loop rather than an algorithm of the trainer: HG-DAgger is round-based (collect with a fixed
novice, then refit on the whole aggregate), keeps only the operator's segments, and
switches the operator between phases, none of which the streaming trainer (workers acting on published
weights, a learner consuming replay) models (docs/ARCHITECTURE.md).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Any

import numpy as np

from tasks.base import StepInterrupted
from tasks.robot import SOURCE_OPERATOR
from unilab_jax.algos.imitation import bc
from unilab_jax.algos.imitation import learner_jax as bc_jax

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class HGDaggerConfig:
    """Phases and the novice's fit (``bc``)."""

    demo_episodes: int = 12
    rounds: int = 3
    episodes_per_round: int = 8
    eval_episodes: int = 12
    max_env_steps: int | None = None  # robot steps of the whole run (None: no cap)
    intervention_weight: int = 1  # times each round's operator row enters the aggregate (1: all rows alike)
    warm_start: bool = True  # each round's refit fine-tunes the previous novice (False: fresh parameters)
    keep_best: bool = False  # a refit whose evaluation falls below the kept novice's is dropped (its data kept)
    refit_steps: int | None = None  # gradient steps of each round's refit (None: bc's budget)
    novice_time: bool = False  # the novice reads the episode time (the critic observation's last column)
    bc: bc.BCConfig = bc.BCConfig(steps=2000)  # every fit's budget (the initial fit's and each refit's)

    def __post_init__(self):
        if self.demo_episodes < 1 or self.rounds < 0 or self.episodes_per_round < 1 or self.eval_episodes < 1:
            raise ValueError(f"HGDaggerConfig: demo_episodes, episodes_per_round and eval_episodes must be "
                             f"positive, rounds >= 0; got {self}")
        if self.refit_steps is not None and self.refit_steps < 1:
            raise ValueError(f"HGDaggerConfig: refit_steps must be positive (or None), got {self.refit_steps}")
        if self.intervention_weight < 1:
            raise ValueError(f"HGDaggerConfig: intervention_weight must be >= 1, got {self.intervention_weight}")
        if self.max_env_steps is not None and self.max_env_steps < 1:
            raise ValueError(f"HGDaggerConfig: max_env_steps must be positive, got {self.max_env_steps}")


@dataclasses.dataclass
class Phase:
    """What one phase collected: rows ``obs`` [N, D] (the novice's observation), ``action`` [N, A] (executed),
    ``source`` [N]; episodes."""

    obs: np.ndarray
    action: np.ndarray
    source: np.ndarray
    successes: list[bool]
    returns: list[float]
    rates: list[float]
    takeovers: list[float]
    steps: int

    @property
    def success_rate(self) -> float:
        return float(np.mean(self.successes)) if self.successes else float("nan")


def _finite_or_none(x: float) -> float | None:
    """``x``, or None where it is not finite: strict JSON (summary.json) has no NaN."""
    return float(x) if np.isfinite(x) else None


class HGDagger:
    def __init__(self, task: Any, config: HGDaggerConfig, seed: int = 0, logdir: str | None = None):
        if not hasattr(task, "set_operator"):
            raise ValueError(f"HG-DAgger needs a robot task with an operator channel, got {task.spec.name}")
        self.task, self.config, self.seed, self.logdir = task, config, seed, logdir
        self.env_steps = 0
        self.t0 = time.perf_counter()
        self.history: list[dict[str, float]] = []

    @property
    def novice_obs_dim(self) -> int:
        return self.task.spec.critic_obs_dim - (0 if self.config.novice_time else 1)

    def novice_obs(self, critic_obs: np.ndarray) -> np.ndarray:
        """critic_obs [N, D] -> what the novice reads [N, ``novice_obs_dim``] (without the time unless
        ``novice_time``)."""
        return critic_obs if self.config.novice_time else critic_obs[:, :-1]

    def _left(self) -> int | None:
        cap = self.config.max_env_steps
        return None if cap is None else cap - self.env_steps

    def collect(self, mode: str, weights: dict | None, episodes: int) -> Phase:
        """Runs ``episodes`` episodes (all envs from a reset; the first ``episodes`` to end count) with the
        operator channel in ``mode``; ``weights`` None: the novice is absent (only ``always`` allows it)."""
        task = self.task
        task.set_operator(mode)
        _, critic_obs = task.reset()
        obs_rows, action_rows, source_rows = [], [], []
        successes, returns, rates, takeovers = [], [], [], []
        ep_return = np.zeros(task.num_envs)
        steps = 0
        zero = np.zeros((task.num_envs, task.spec.action_dim), np.float32)
        while len(successes) < episodes and (self._left() is None or self._left() > 0):
            obs = self.novice_obs(critic_obs)
            action = zero if weights is None else bc.act(weights, obs, None)[0]
            try:
                out = task.step(action)
            except StepInterrupted as e:  # a lost robot or a protective stop: no transition, every env starts over
                log.warning("HG-DAgger %s: step interrupted, the episodes in flight are dropped: %s", mode, e)
                critic_obs, ep_return[:] = e.critic_obs, 0.0
                continue
            obs_rows.append(obs)
            action_rows.append(out.extras.get("action", action))
            source_rows.append(out.extras["source"])
            ep_return += out.reward
            steps += task.num_envs
            self.env_steps += task.num_envs
            for i in np.flatnonzero(out.terminated | out.truncated):
                if len(successes) < episodes:
                    successes.append(bool(out.terminated[i]))
                    returns.append(float(ep_return[i]))
                    rates.append(float(out.extras["intervention_rate"][i]))
                    takeovers.append(float(out.extras["interventions"][i]))
                ep_return[i] = 0.0
            critic_obs = out.critic_obs
        cat = (lambda rows, shape: np.concatenate(rows) if rows else np.zeros(shape, np.float32))
        return Phase(cat(obs_rows, (0, self.novice_obs_dim)), cat(action_rows, (0, task.spec.action_dim)),
                     cat(source_rows, (0,)), successes, returns, rates, takeovers, steps)

    def _log(self, logger: Any, scalars: dict[str, float]) -> None:
        scalars = {**scalars, "hgdagger/wall_s": time.perf_counter() - self.t0, "hgdagger/env_steps": self.env_steps}
        self.history.append(scalars)
        if logger is not None:
            logger.log(self.env_steps, scalars)
        shown = {k.split("/")[-1]: round(v, 3) for k, v in scalars.items() if k.startswith(("eval/", "hgdagger/"))}
        print(f"hg-dagger {scalars['hgdagger/round']:.0f}: {shown}", flush=True)

    def run(self) -> dict[str, Any]:
        """Demonstrations, the initial fit, then the gated rounds; returns the summary (also in the log), JSON-ready:
        a success rate of an evaluation the step cap cut to no episode is None there (NaN in ``history``)."""
        cfg = self.config
        logger = None
        if self.logdir:
            from unilab_jax.metrics import MetricLogger

            logger = MetricLogger(self.logdir)
        try:
            demos = self.collect("always", None, cfg.demo_episodes)
            keep = demos.source == SOURCE_OPERATOR
            data_obs, data_action = demos.obs[keep], demos.action[keep]
            weights, fit = bc_jax.fit(data_obs, data_action, cfg.bc, seed=self.seed)
            evaluation = self.collect("off", weights, cfg.eval_episodes)
            self._log(logger, {"hgdagger/round": 0, "eval/success_rate": evaluation.success_rate,
                               "eval/return": float(np.mean(evaluation.returns or [np.nan])),
                               "hgdagger/dataset_rows": len(data_obs), "hgdagger/operator_rows": len(data_obs),
                               "hgdagger/demo_success_rate": demos.success_rate, "hgdagger/bc_loss": fit["loss"],
                               "hgdagger/eval_steps": evaluation.steps})
            best = evaluation.success_rate
            refit = cfg.bc if cfg.refit_steps is None else dataclasses.replace(cfg.bc, steps=cfg.refit_steps)
            for r in range(1, cfg.rounds + 1):
                if self._left() is not None and self._left() <= 0:
                    break
                gated = self.collect("gate", weights, cfg.episodes_per_round)
                keep = gated.source == SOURCE_OPERATOR  # only the operator's intervention segments
                data_obs = np.concatenate([data_obs, *[gated.obs[keep]] * cfg.intervention_weight])
                data_action = np.concatenate([data_action, *[gated.action[keep]] * cfg.intervention_weight])
                candidate, fit = bc_jax.fit(data_obs, data_action, refit, seed=self.seed + r,
                                            init=weights if cfg.warm_start else None)
                evaluation = self.collect("off", candidate, cfg.eval_episodes)
                kept = not cfg.keep_best or evaluation.success_rate >= best
                if kept:
                    weights, best = candidate, evaluation.success_rate
                self._log(logger, {
                    "hgdagger/round": r, "eval/success_rate": evaluation.success_rate,
                    "eval/return": float(np.mean(evaluation.returns or [np.nan])),
                    "hgdagger/dataset_rows": len(data_obs), "hgdagger/operator_rows": int(keep.sum()),
                    "hgdagger/intervention_rate": float(np.mean(gated.rates or [np.nan])),
                    "hgdagger/interventions": float(np.mean(gated.takeovers or [np.nan])),
                    "hgdagger/round_success_rate": gated.success_rate, "hgdagger/bc_loss": fit["loss"],
                    "hgdagger/kept": float(kept), "hgdagger/kept_success_rate": best,
                    "hgdagger/eval_steps": evaluation.steps})
        finally:
            if logger is not None:
                logger.close()
        self.weights = weights
        rates = [h["eval/success_rate"] for h in self.history]
        evaluated = [r for r in rates if np.isfinite(r)]  # an evaluation the step cap cut to no episode is nan
        last = self.history[-1]
        return {"rounds": int(last["hgdagger/round"]), "env_steps": self.env_steps,
                "wall_s": time.perf_counter() - self.t0, "logdir": self.logdir,
                "initial_success_rate": _finite_or_none(rates[0]),
                "final_success_rate": evaluated[-1] if evaluated else None,
                "dataset_rows": int(last["hgdagger/dataset_rows"]),
                "success_rates": [_finite_or_none(r) for r in rates], "kept_success_rate": _finite_or_none(best)}
