"""A toy task whose outputs turn NaN/Inf on a fixed schedule (tests of the worker's non-finite masking).

Importing the module registers ``toy_nan`` (offers ``reset_envs``, so the worker resets a bad env)
and ``toy_nan_noreset`` (does not). The corruption is in the outputs only, never in the state, so the
expected masked rows follow from the schedule alone: :func:`expected_rows`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from tasks import base


@dataclasses.dataclass(frozen=True)
class ToyNanConfig:
    episode_length: int = 10_000
    resettable: bool = True


def reward_bad(t: int, m: int) -> np.ndarray:
    """[M] bool: envs whose reward term ``b`` is NaN (odd envs) or +Inf (even envs) at task step ``t``."""
    return (t + np.arange(m)) % 7 == 3


def obs_bad(t: int, m: int) -> np.ndarray:
    """[M] bool: envs whose successor observation holds an Inf (actor) and a NaN (critic) at step ``t``."""
    return (t + 2 * np.arange(m)) % 11 == 5


def expected_rows(steps: int, m: int, resettable: bool) -> np.ndarray:
    """[steps, M] bool: the rows a worker must mask in its first ``steps`` steps.

    Without ``reset_envs`` the corrupted observation is also the next step's input, so that row is
    masked too (its action, computed from it, is non-finite as well).
    """
    rows = np.stack([reward_bad(t, m) | obs_bad(t, m) for t in range(steps)])
    if not resettable:
        rows[1:] |= np.stack([obs_bad(t, m) for t in range(steps - 1)])
    return rows


class ToyNan(base.Task):
    def __init__(self, config: ToyNanConfig, num_envs: int, seed: int):
        super().__init__(config, num_envs, seed)
        self.spec = base.TaskSpec(name="toy_nan", obs_dim=3, critic_obs_dim=4, action_dim=1,
                                  episode_length=config.episode_length, ctrl_dt=0.02, reward_terms=("a", "b"))
        self._rng = np.random.default_rng(seed)
        self.x = np.zeros((num_envs, 3))
        self.steps = np.zeros(num_envs, np.int64)
        self.t = 0

    def _observe(self, idx=slice(None)) -> tuple[np.ndarray, np.ndarray]:
        obs = self.x[idx].astype(np.float32)
        return obs, np.concatenate([obs, self.steps[idx, None].astype(np.float32)], axis=1)

    def _reset(self, idx: np.ndarray) -> None:
        self.x[idx] = self._rng.uniform(-1, 1, size=(idx.size, 3))
        self.steps[idx] = 0

    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        self._reset(np.arange(self.num_envs))
        return self._observe()

    def step(self, action: np.ndarray) -> base.StepOut:
        a = np.nan_to_num(np.clip(np.asarray(action, np.float64).reshape(self.num_envs, 1), -1, 1))
        self.x = 0.9 * self.x + 0.1 * a
        self.steps += 1
        next_obs, next_cobs = self._observe()
        terms = {"a": (-0.1 * np.square(self.x).sum(1)).astype(np.float32),
                 "b": np.full(self.num_envs, 0.01, np.float32)}
        r_bad, o_bad = reward_bad(self.t, self.num_envs), obs_bad(self.t, self.num_envs)
        terms["b"][r_bad] = np.where(np.arange(self.num_envs)[r_bad] % 2, np.nan, np.inf)
        next_obs[o_bad, 1] = np.inf
        next_cobs[o_bad, 2] = np.nan
        self.t += 1
        trunc = self.steps >= self.config.episode_length
        obs, cobs = next_obs.copy(), next_cobs.copy()
        done = np.flatnonzero(trunc)
        if done.size:
            self._reset(done)
            obs[done], cobs[done] = self._observe(done)
        reward = (terms["a"] + terms["b"]).astype(np.float32)
        return base.StepOut(obs, cobs, next_obs, next_cobs, reward, np.zeros(self.num_envs, bool), trunc, terms)


class ToyNanResettable(ToyNan):
    def reset_envs(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._reset(idx)
        return self._observe(idx)


def make(config: ToyNanConfig, num_envs: int, seed: int) -> ToyNan:
    return (ToyNanResettable if config.resettable else ToyNan)(config, num_envs, seed)


base.register("toy_nan", make, ToyNanConfig)
base.register("toy_nan_noreset", make, lambda: ToyNanConfig(resettable=False))
