"""A finished (or running) training run read back from its logdir: the policy ``play`` and ``export`` use.

``load(logdir, checkpoint=None)`` rebuilds what the trainer had from the checkpoint's record (algorithm,
task, task overrides, algorithm config, platform), restores the whole training state into the learner's
own template (as ``--resume`` does) and returns the numpy weights the workers act with, so the policy
run here is exactly the one the trainer's evaluations run (``algo.act(weights, obs, zeros, True)``).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from types import ModuleType
from typing import Any

import numpy as np

from unilab_jax import algos, nets
from unilab_jax import xp as shim
from unilab_jax.checkpoint import Checkpointer
from unilab_jax.config import apply_overrides


@dataclasses.dataclass(frozen=True)
class SavedRun:
    """The deterministic policy of one checkpoint and what is needed to run it on its task."""

    logdir: str
    step: int  # the checkpoint's env step
    algo: str  # registered algorithm name
    module: ModuleType  # its declaration (``act``)
    config: Any  # its frozen config
    task: str
    task_overrides: dict[str, Any]  # the run's, as recorded (strings, parsed by the task config)
    seed: int
    weights: dict  # numpy weights, as published to the workers
    spec: Any  # the task's TaskSpec

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic action [M, A] float32 for ``obs`` [M, obs_dim]."""
        zeros = np.zeros((obs.shape[0], self.spec.action_dim), np.float32)
        action, _ = self.module.act(self.weights, np.asarray(obs, np.float32), zeros, True)
        return np.asarray(action, np.float32)

    def make_task(self, num_envs: int, seed: int = 0, overrides: Mapping[str, Any] | None = None) -> Any:
        """A fresh instance of the run's task with its overrides, then ``overrides`` on top."""
        import tasks

        return tasks.make(self.task, num_envs, seed=seed, overrides={**self.task_overrides, **dict(overrides or {})})


def load(logdir: str, checkpoint: int | None = None, task_overrides: Mapping[str, Any] | None = None) -> SavedRun:
    """The policy of checkpoint ``checkpoint`` (env step; default the latest) of the run in ``logdir``.

    ``task_overrides`` go on top of the run's own for the task built to read the spec (a robot run's servers
    are gone after it: ``robots=()`` plays it on in-process robots).
    Raises FileNotFoundError (no such folder, no checkpoint, no such step: the message lists the steps)."""
    import tasks

    ckpt_dir = os.path.join(os.path.abspath(logdir), "checkpoints")
    if not os.path.isdir(ckpt_dir):
        raise FileNotFoundError(f"{logdir!r} holds no checkpoints folder: not the logdir of a training run")
    ckpt = Checkpointer(ckpt_dir)
    try:
        steps = ckpt.all_steps()
        if not steps:
            raise FileNotFoundError(f"no checkpoint under {ckpt_dir}")
        if checkpoint is not None and int(checkpoint) not in steps:
            raise FileNotFoundError(f"no checkpoint of step {checkpoint} under {ckpt_dir}; steps: {steps}")
        step = steps[-1] if checkpoint is None else int(checkpoint)
        meta = ckpt.read(step)[2]
        module = algos.get(meta["algo"])
        config = apply_overrides(module.Config(), meta["config"])
        run = meta["run"]
        overrides = dict(meta.get("task_overrides", {}))
        probe = tasks.make(meta["task"], num_envs=1, seed=int(run["seed"]),
                           overrides={**overrides, **dict(task_overrides or {})})
        spec = probe.spec
        probe.close()
        xp = shim.get(run["platform"])
        learner = algos.make_learner(module, run["platform"], config, spec)
        state, _ = ckpt.restore(learner.init(xp.random.key(int(run["seed"]))), lambda a, like: xp.from_numpy(a),
                                step=step)
        weights = nets.to_numpy(learner.weights(state))
    finally:
        ckpt.close()
    return SavedRun(logdir=os.path.abspath(logdir), step=step, algo=meta["algo"], module=module, config=config,
                    task=meta["task"], task_overrides=overrides, seed=int(run["seed"]), weights=weights, spec=spec)
