"""``<task>_hist`` variants: a task's observation as a history of frames, optionally with its extrinsics.

Teacher/student and history-encoder methods (HORA, HIM) need, at every step, the last ``H``
proprioceptive frames and (for a privileged teacher, or as the student's regression target) the
domain-randomisation parameters. The rollout workers build tasks by name and the trainer's
evaluation calls a stateless ``act(weights, obs, ...)``, so the history is kept *by the task*: a
variant wraps the base task, holds ``[M, H, d]`` frames in numpy (a shift plus a masked refill of the
envs that reset, no per-env Python loop) and returns them as the observation. Every consumer of
observations (workers, buffers, evaluation, walking metric) then works unchanged.

Observation layout, ``obs_dim = H * d + p``::

    [frame_{t-H+1}, ..., frame_t | extrinsics]     frame = [base obs without ``history_exclude`` columns
                                                            (, previous action if ``history_actions``)]

with ``p = privileged_dim`` when ``history_extrinsics`` (else 0). A frame is the base observation
with the excluded columns removed (e.g. Go1's measured base velocity, for an estimator that must
infer it), followed by the action applied before it (clipped to [-1, 1]; zeros after a reset) when
``history_actions`` -- for tasks whose observation lacks it (cart-pole; Go1's already has it), since
a response says little about the dynamics without the command that caused it (HORA's history holds
joint positions *and* targets). After a reset the history is the first frame repeated. ``next_obs`` is the history that
ends with the true successor (before the auto-reset), so ``obs == next_obs`` exactly where no episode
ended. With ``history_extrinsics`` the critic observation gets the extrinsics appended too (a
privileged critic may use them). The spec is a :class:`HistorySpec` carrying ``frame_dim``,
``history_len`` and ``extrinsics_in_obs``, so learners can split observations without a config of
their own. Storage grows with ``H``: obs and next_obs each hold ``H * d + p`` floats per transition.

``register_variant(name)`` adds the variant of any registered task that exposes ``extrinsics``
(for ``history_extrinsics``); the built-in ones are ``cartpole_balance_hist``,
``go1_joystick_flat_hist``, ``go1_joystick_rough_hist``, ``go2_joystick_flat_hist``, ``go2_joystick_rough_hist`` and
``allegro_rotate_hist``.
Other attributes (``command``, ``base_velocity()``, ``extrinsics``, ``dr``, ...) are forwarded to the wrapped task,
and so are its per-episode metrics (``spec.episode_metrics``, ``StepOut.extras``).
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from typing import Any

import numpy as np

from tasks import base

SUFFIX = "_hist"


@dataclasses.dataclass(frozen=True)
class HistorySpec(base.TaskSpec):
    """A ``TaskSpec`` that says how the observation splits into frames and extrinsics."""

    frame_dim: int = 0
    history_len: int = 1
    extrinsics_in_obs: bool = False


def split_obs(spec: HistorySpec, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``obs [..., obs_dim] -> (frames [..., H, d], extrinsics [..., p])`` (p may be 0)."""
    h, d = spec.history_len, spec.frame_dim
    frames = obs[..., : h * d].reshape(*obs.shape[:-1], h, d)
    return frames, obs[..., h * d:]


class HistoryTask(base.Task):
    def __init__(self, inner: base.Task, config: Any, name: str):
        super().__init__(config, inner.num_envs, inner.seed)
        if config.history_len < 1:
            raise ValueError(f"history_len must be at least 1, got {config.history_len}")
        s = inner.spec
        excluded = set(config.history_exclude)
        if any(not 0 <= c < s.obs_dim for c in excluded):
            raise ValueError(f"history_exclude {config.history_exclude} outside the {s.obs_dim} observation columns")
        self.inner = inner
        self._keep = np.array([c for c in range(s.obs_dim) if c not in excluded], dtype=np.int64)
        if self._keep.size == 0:
            raise ValueError("history_exclude removes every observation column")
        self._ext = bool(config.history_extrinsics)
        if self._ext and not s.privileged_dim:
            raise ValueError(f"{s.name} has no extrinsics (privileged_dim 0); set history_extrinsics=False")
        p = s.privileged_dim if self._ext else 0
        self._actions = bool(config.history_actions)
        h, d = int(config.history_len), int(self._keep.size) + (s.action_dim if self._actions else 0)
        self.spec = HistorySpec(
            name=name, obs_dim=h * d + p, critic_obs_dim=s.critic_obs_dim + p, action_dim=s.action_dim,
            episode_length=s.episode_length, ctrl_dt=s.ctrl_dt, reward_terms=s.reward_terms,
            privileged_dim=s.privileged_dim, episode_metrics=s.episode_metrics, frame_dim=d, history_len=h,
            extrinsics_in_obs=self._ext,
        )
        self._frames = np.zeros((self.num_envs, h, d), np.float32)

    def _frame(self, obs: np.ndarray, action: np.ndarray | None) -> np.ndarray:
        """[M, d] frames of ``obs``; ``action`` is the one that led to it (None: a reset, zeros)."""
        f = obs[:, self._keep]
        if not self._actions:
            return f
        a = np.zeros((self.num_envs, self.spec.action_dim), np.float32) if action is None else action
        return np.concatenate([f, a], axis=1)

    def __getattr__(self, attr: str) -> Any:
        # Only reached for names this wrapper does not define: the base task's API (command, dr, ...).
        if attr in ("inner", "eval_tracker"):  # eval_tracker: the property above decides
            raise AttributeError(attr)
        return getattr(self.inner, attr)

    def render_scene(self, env: int = 0) -> tuple[Any, Any]:
        return self.inner.render_scene(env)

    @property
    def eval_tracker(self):
        """The wrapped task's ``eval_tracker`` with this variant as its ``stepper`` (so evaluation steps the
        variant and sees the history observation); absent when the wrapped task has none, or one that takes
        no ``stepper``."""
        make = self.inner.eval_tracker
        if "stepper" not in inspect.signature(make).parameters:
            raise AttributeError("eval_tracker")
        return functools.partial(make, stepper=self)

    def _pack(self, frames: np.ndarray, critic: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        flat = frames.reshape(self.num_envs, -1)
        if not self._ext:
            return flat.copy(), critic
        ext = np.asarray(self.inner.extrinsics, np.float32)
        return np.concatenate([flat, ext], axis=1), np.concatenate([critic, ext], axis=1)

    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        obs, cobs = self.inner.reset()
        self._frames[:] = self._frame(obs, None)[:, None]
        return self._pack(self._frames, cobs)

    def step(self, action: np.ndarray) -> base.StepOut:
        out = self.inner.step(action)
        applied = np.nan_to_num(np.clip(np.asarray(action, np.float32).reshape(self.num_envs, -1), -1.0, 1.0))
        # The successor's history: shift every env's frames by one and append the new frame.
        nxt = np.concatenate([self._frames[:, 1:], self._frame(out.next_obs, applied)[:, None]], axis=1)
        frames = nxt.copy()
        ended = np.flatnonzero(out.terminated | out.truncated)
        if ended.size:  # a new episode starts from its first frame repeated
            frames[ended] = self._frame(out.obs, None)[ended][:, None]
        self._frames = frames
        next_obs, next_cobs = self._pack(nxt, out.next_critic_obs)
        obs, cobs = self._pack(frames, out.critic_obs)
        return base.StepOut(obs, cobs, next_obs, next_cobs, out.reward, out.terminated, out.truncated,
                            out.reward_terms, out.extras)

    def close(self) -> None:
        self.inner.close()


@functools.cache
def variant_config_class(base_name: str) -> type:
    """The config of ``<base_name>_hist``: the base task's fields plus ``history_len`` (1),
    ``history_extrinsics`` (True), ``history_actions`` (False) and ``history_exclude`` (no columns)."""
    base_cls = type(base.default_config(base_name))
    config_cls = dataclasses.make_dataclass(
        base_cls.__name__ + "History",
        [("history_len", int, dataclasses.field(default=1)),
         ("history_extrinsics", bool, dataclasses.field(default=True)),
         ("history_actions", bool, dataclasses.field(default=False)),
         ("history_exclude", tuple[int, ...], dataclasses.field(default=()))],
        bases=(base_cls,), frozen=True)
    config_cls.__doc__ = f"``{base_name}`` fields plus the history options (see tasks/history.py)."
    return config_cls


def variant_default_config(base_name: str) -> Any:
    """``<base_name>_hist``'s default config (the base task's defaults, no history options changed)."""
    return variant_config_class(base_name)(**dataclasses.asdict(base.default_config(base_name)))


def make_variant(base_name: str, config: Any, num_envs: int, seed: int) -> HistoryTask:
    """``<base_name>_hist``'s factory: the base task built from its own fields of ``config``, wrapped."""
    base_cls = type(base.default_config(base_name))
    inner_config = base_cls(**{f.name: getattr(config, f.name) for f in dataclasses.fields(base_cls)})
    return HistoryTask(base.make_from_config(base_name, inner_config, num_envs, seed), config, base_name + SUFFIX)


def register_variant(base_name: str) -> str:
    """Registers ``<base_name>_hist`` for any registered task; returns the new name. (The built-in
    variants are in ``tasks.base``'s table, which reaches the two functions above by name.)"""
    name = base_name + SUFFIX
    base.register(name, functools.partial(make_variant, base_name),
                  functools.partial(variant_default_config, base_name))
    return name
