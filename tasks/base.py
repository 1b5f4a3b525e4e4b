"""Task API, the end of a step several tasks share (``finish_step``), and the open task registry.

A task owns a batch of ``num_envs`` MuJoCo environments on the CPU and steps them together::

    task = tasks.make("cartpole_balance", num_envs=64, seed=0, overrides={"episode_length": 200})
    obs, critic_obs = task.reset()                  # [M, obs_dim], [M, critic_obs_dim] float32
    out = task.step(action)                         # action [M, action_dim] float32
    out.obs / out.critic_obs                        # next observation, AFTER auto-reset
    out.next_obs / out.next_critic_obs              # true successor, BEFORE auto-reset (for
                                                    # bootstrapping at truncation, replay buffers)
    out.reward [M], out.terminated [M] bool, out.truncated [M] bool (time limit; never both)
    out.reward_terms {name: [M]}                    # each term's scaled contribution this step
    task.images()                                   # uint8 [M, H, W, C] of obs, tasks with spec.image_shape

Environments that end (terminated or truncated) are reset inside ``step``; nothing per env happens in
Python beyond the MuJoCo step calls. ``finish_step`` is that end of a step (unstable envs masked and
truncated, end flags, auto-reset) for the Go1, walking, G1-tracking and Allegro tasks. Observation/reward
math is written against the array-API shim so the MJX variant can reuse it.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from unilab_jax.config import apply_overrides
from unilab_jax.lazy import load


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    """What a task declares; buffers in shared memory are built from it."""

    name: str
    obs_dim: int  # actor observation
    critic_obs_dim: int  # privileged critic observation
    action_dim: int
    episode_length: int  # control steps before truncation
    ctrl_dt: float
    reward_terms: tuple[str, ...]
    privileged_dim: int = 0  # extrinsics vector for teacher/student methods (0: none)
    # Per-transition fields the task writes besides the standard ones, ``(name, shape, dtype)`` (values in
    # ``StepOut.extras``; e.g. the robot tasks' ``source``: who chose the action, policy 0 / operator 1).
    transition_fields: tuple[tuple[str, tuple[int, ...], str], ...] = ()
    # Per-episode quantities (values in ``StepOut.extras``, read where an episode ended), logged as means
    # over the episodes ended since the previous log (``WorkerPool.stats()["episode_metrics"]``).
    episode_metrics: tuple[str, ...] = ()
    # True where an episode terminates only by succeeding (the robot tasks): episode and evaluation logs
    # then report the terminated fraction as ``success_rate``.
    success_on_termination: bool = False
    # ``(H, W, C)`` of the task's image observation (uint8, channels last; () when it has none). A task with
    # images lists ``image`` / ``next_image`` of this shape in ``transition_fields`` (the images of ``obs`` and
    # of ``next_obs``, before auto-reset) and returns the images of its current observations from ``images()``.
    image_shape: tuple[int, ...] = ()


class StepOut(NamedTuple):
    obs: np.ndarray
    critic_obs: np.ndarray
    next_obs: np.ndarray
    next_critic_obs: np.ndarray
    reward: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    reward_terms: dict[str, np.ndarray]
    # The values of ``spec.transition_fields`` and ``spec.episode_metrics`` ([M, ...] each), and ``action``
    # [M, A] where the task executed another action than the policy's (an operator took over).
    extras: Mapping[str, np.ndarray] | None = None


class StepInterrupted(Exception):
    """Raised by ``Task.step`` when the step could not be completed (e.g. a robot was lost, and the task
    waited until it or another robot answered again): the step produced no transition, every env was
    reset, and ``obs`` / ``critic_obs`` are the observations the next step starts from."""

    def __init__(self, reason: str, obs: np.ndarray, critic_obs: np.ndarray):
        super().__init__(reason)
        self.obs, self.critic_obs = obs, critic_obs

    def __reduce__(self) -> tuple:  # pickled whole: an evaluation process raises it to the trainer
        return type(self), (str(self), self.obs, self.critic_obs)


def _nothing() -> None:
    return None


class Task(abc.ABC):
    """Base class of batched CPU tasks. Subclasses set ``spec`` in ``__init__``.

    ``keepalive``: a task that may block for long inside ``step`` (waiting for a lost robot) calls
    ``self.keepalive()`` at least every second while it waits; a rollout worker sets it to its own
    liveness check (which heartbeats and raises when the pool stops the worker)."""

    spec: TaskSpec
    config: Any
    keepalive: Callable[[], None] = staticmethod(_nothing)

    def __init__(self, config: Any, num_envs: int, seed: int):
        if num_envs <= 0:
            raise ValueError(f"num_envs must be positive, got {num_envs}")
        self.config = config
        self.num_envs = int(num_envs)
        self.seed = int(seed)

    @abc.abstractmethod
    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        """Resets every environment; returns (obs, critic_obs)."""

    @abc.abstractmethod
    def step(self, action: np.ndarray) -> StepOut:
        """Steps every environment one control step (auto-resetting those that end)."""

    def close(self) -> None:  # noqa: B027  (optional hook, not abstract)
        """Releases resources (nothing by default)."""

    def images(self) -> np.ndarray:
        """uint8 ``[M, *spec.image_shape]``: the images of the observations ``reset`` / ``step`` returned last
        (what the policy acts on; tasks with ``spec.image_shape`` implement it)."""
        raise NotImplementedError(f"task {self.spec.name!r} has no image observation")

    def render_scene(self, env: int = 0) -> tuple[Any, Any]:
        """``(mujoco.MjModel, mujoco.MjData)`` of env ``env`` in its current state (kinematics computed), for
        ``mujoco.Renderer`` (``unilab_jax.apps.play``, training clips). Tasks that step a ``BatchedSim`` in
        ``self.sim`` get it from there; a task without one overrides this or cannot be rendered."""
        sim = getattr(self, "sim", None)
        if sim is None:
            raise NotImplementedError(f"task {self.spec.name!r} has no MuJoCo scene to render (no render_scene)")
        return sim.scene(env)


def with_reward_scales(scales: Mapping[str, float]) -> Callable[[type], type]:
    """Class decorator for a frozen task config: a float field ``scale_<term>`` per reward term of ``scales``
    (``{term: default scale}``, in the task's term order), so a task names each term and its scale once."""

    def decorate(cls: type) -> type:
        fields = [(f"scale_{term}", float, dataclasses.field(default=float(scale))) for term, scale in scales.items()]
        out = dataclasses.make_dataclass(cls.__name__, fields, bases=(cls,), frozen=True)
        out.__module__, out.__qualname__, out.__doc__ = cls.__module__, cls.__qualname__, cls.__doc__
        return out

    return decorate


def reward_scales(config: Any, terms: Sequence[str]) -> dict[str, float]:
    """``{term: config.scale_<term>}`` for ``terms``."""
    return {name: float(getattr(config, f"scale_{name}")) for name in terms}


def finish_step(next_obs, next_cobs, reward, scaled, done, unstable, at_limit, reset_and_observe):
    """The end of a task step shared by the Go1, walking, G1-tracking and Allegro tasks: instability masking,
    end flags, auto-reset.

    ``unstable [M]`` (MuJoCo divergence) is widened by any non-finite observation or reward; those envs are
    truncated with zeroed outputs. ``done [M]`` terminates the others; ``at_limit [M]`` truncates them.
    ``reset_and_observe(idx)`` resets envs ``idx`` and returns the whole batch's (obs, critic_obs), of
    which rows ``idx`` replace the successors in ``StepOut.obs``. Returns (StepOut, number of unstable envs).
    """
    unstable = unstable | ~(
        np.isfinite(next_obs).all(axis=1) & np.isfinite(next_cobs).all(axis=1) & np.isfinite(reward)
    )
    n_unstable = int(unstable.sum())
    if n_unstable:
        next_obs[unstable] = 0.0
        next_cobs[unstable] = 0.0
        reward = np.where(unstable, 0.0, reward)
        scaled = {k: np.where(unstable, 0.0, v) for k, v in scaled.items()}
    term = done & ~unstable
    trunc = (at_limit | unstable) & ~term
    next_obs = next_obs.astype(np.float32)
    next_cobs = next_cobs.astype(np.float32)
    obs, cobs = next_obs, next_cobs
    ended = np.flatnonzero(term | trunc)
    if ended.size:
        o2, c2 = reset_and_observe(ended)
        obs, cobs = next_obs.copy(), next_cobs.copy()
        obs[ended] = o2[ended]
        cobs[ended] = c2[ended]
    out = StepOut(obs, cobs, next_obs, next_cobs, reward.astype(np.float32), term, trunc,
                  {k: v.astype(np.float32) for k, v in scaled.items()})
    return out, n_unstable


class _ByName:
    """A registered callable held as ``"module:function"`` (plus leading arguments), imported when first
    called: the registry names the built-in tasks without importing them."""

    def __init__(self, target: str, *args: Any):
        self.target, self.args = target, args
        self.__module__ = target.partition(":")[0]

    def __call__(self, *args: Any) -> Any:
        return load(self.target)(*self.args, *args)


@dataclasses.dataclass(frozen=True)
class _Entry:
    factory: Callable[..., Task]
    default_config: Callable[[], Any]


def _builtin(module: str) -> _Entry:
    return _Entry(_ByName(f"{module}:make"), _ByName(f"{module}:default_config"))


def _history(base_name: str) -> _Entry:
    return _Entry(_ByName("tasks.history:make_variant", base_name),
                  _ByName("tasks.history:variant_default_config", base_name))


# Built-in tasks by module path; a task's module is imported when it is first built or configured,
# so this module imports no task module (and listing the tasks imports none).
_REGISTRY: dict[str, _Entry] = {
    "cartpole_balance": _builtin("tasks.cartpole"),
    "go1_joystick_flat": _builtin("tasks.go1_joystick"),
    "go1_joystick_rough": _builtin("tasks.go1_rough"),
    "go2_joystick_flat": _builtin("tasks.go2_joystick"),
    "g1_walk_flat": _builtin("tasks.g1_walk"),
    "go2_joystick_rough": _Entry(_ByName("tasks.walking_rough:make_go2"),
                                 _ByName("tasks.walking_rough:go2_default_config")),
    "g1_walk_rough": _Entry(_ByName("tasks.walking_rough:make_g1"), _ByName("tasks.walking_rough:g1_default_config")),
    "allegro_rotate": _builtin("tasks.allegro_rotate"),
    "g1_track": _builtin("tasks.g1_track"),
    "robot_pick_place": _Entry(_ByName("tasks.robot:make", "pick_place"), _ByName("tasks.robot:default_config")),
    "robot_peg_insertion": _Entry(_ByName("tasks.robot:make", "peg_insertion"),
                                  _ByName("tasks.robot:default_config")),
    "robot_reach": _Entry(_ByName("tasks.robot:make", "reach"), _ByName("tasks.robot:default_config")),
    **{f"{name}_hist": _history(name)
       for name in ("cartpole_balance", "go1_joystick_flat", "go1_joystick_rough", "go2_joystick_flat",
                    "go2_joystick_rough", "allegro_rotate")},
}


def register(name: str, factory: Callable[..., Task], default_config: Callable[[], Any]) -> None:
    """Registers a task: ``factory(config, num_envs, seed) -> Task``; ``default_config() -> dataclass``."""
    _REGISTRY[name] = _Entry(factory, default_config)


def names() -> list[str]:
    return sorted(_REGISTRY)


GYM_PREFIX = "gym:"  # ``gym:ENV_ID``: a Gymnasium environment (tasks/gym_env.py), resolved by name


def _entry(name: str) -> _Entry:
    if name.startswith(GYM_PREFIX) and name not in _REGISTRY:
        env_id = name[len(GYM_PREFIX):]
        return _Entry(_ByName("tasks.gym_env:make", env_id), _ByName("tasks.gym_env:default_config", env_id))
    if name not in _REGISTRY:
        raise ValueError(f"unknown task {name!r}; registered tasks: {names()} (or gym:ENV_ID for a Gymnasium "
                         "environment)")
    return _REGISTRY[name]


def default_config(name: str) -> Any:
    return _entry(name).default_config()


def make_from_config(name: str, config: Any, num_envs: int, seed: int = 0) -> Task:
    return _entry(name).factory(config, num_envs, seed)


def make(name: str, num_envs: int, seed: int = 0, overrides: Mapping[str, Any] | None = None) -> Task:
    return make_from_config(name, apply_overrides(default_config(name), overrides), num_envs, seed)
