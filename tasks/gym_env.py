"""``gym:ENV_ID``: any Gymnasium environment with Box observation and action spaces as a task.

    python experiments/sac_pendulum.py                       # gym:Pendulum-v1
    python experiments/sac_cartpole.py --task=gym:HalfCheetah-v5 --task_config=episode_length=1000

Each task holds a ``gymnasium.vector.SyncVectorEnv`` of ``num_envs`` copies of the environment in
same-step auto-reset mode: ``step`` returns the observation after the reset of an environment that ended
(``obs``) and its final observation (``next_obs``), as the task contract asks. Actions in [-1, 1] are
clipped and mapped linearly onto the action space's bounds (which must be finite); observations of any
Box shape are flattened and cast to float32. Termination and truncation stay apart (a step that is both
counts as terminated). The reward is the environment's own, one term ``reward``.

Environment ``i`` of a task seeded ``seed`` is reset with the ``i``-th number of
``numpy.random.SeedSequence(seed)``, so workers (seeded apart) draw different episodes. Gymnasium is
imported here only, when a ``gym:`` task is first configured.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from tasks import base
from unilab_jax.config import ConfigError

PREFIX = "gym:"
REWARD_TERMS = ("reward",)
DEFAULT_EPISODE_LENGTH = 1000  # for environments registered without a time limit


@dataclasses.dataclass(frozen=True)
class GymConfig:
    """Configuration of a ``gym:ENV_ID`` task (override with ``--task_config``)."""

    episode_length: int = DEFAULT_EPISODE_LENGTH  # steps before truncation (default: the env's max_episode_steps)

    def __post_init__(self) -> None:
        if self.episode_length < 1:
            raise ConfigError(f"episode_length must be at least 1, got {self.episode_length}")


def _gymnasium() -> Any:
    try:
        import gymnasium
    except ImportError as e:
        raise ValueError(f"gym: tasks need Gymnasium ({e}); pip install 'unilab-jax[gym]'") from e
    return gymnasium


def _make_env(env_id: str, episode_length: int | None = None) -> Any:
    """One environment, with its time limit set to ``episode_length`` (None: the registered one); unknown
    ids, missing dependencies and spaces a continuous policy cannot drive raise ``ValueError``."""
    gym = _gymnasium()
    try:
        env = gym.make(env_id, max_episode_steps=episode_length)
    except (gym.error.Error, ImportError) as e:
        raise ValueError(f"Gymnasium environment {env_id!r} cannot be made: {e}") from e
    for kind, space in (("observation", env.observation_space), ("action", env.action_space)):
        if not isinstance(space, gym.spaces.Box):
            env.close()
            raise ValueError(f"Gymnasium environment {env_id!r}: its {kind} space {space} is not a Box; gym: tasks "
                             "need Box observation and action spaces (continuous control)")
    low, high = env.action_space.low, env.action_space.high
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
        env.close()
        raise ValueError(f"Gymnasium environment {env_id!r}: action bounds {env.action_space} must be finite to map "
                         "actions in [-1, 1] onto them")
    return env


def default_config(env_id: str) -> GymConfig:
    """Checks that ``env_id`` can be made and driven; its episode length is the registered time limit."""
    env = _make_env(env_id)
    limit = env.spec.max_episode_steps if env.spec is not None else None
    env.close()
    return GymConfig(episode_length=int(limit) if limit else DEFAULT_EPISODE_LENGTH)


def _ctrl_dt(env: Any) -> float:
    """Seconds per step: the env's ``dt`` (MuJoCo and most classic-control envs), else 1 / its render fps."""
    dt = getattr(env.unwrapped, "dt", None)
    if dt:
        return float(dt)
    fps = env.metadata.get("render_fps")
    return 1.0 / float(fps) if fps else 1.0


class GymTask(base.Task):
    def __init__(self, env_id: str, config: GymConfig, num_envs: int, seed: int):
        super().__init__(config, num_envs, seed)
        gym = _gymnasium()
        probe = _make_env(env_id, config.episode_length)
        self.spec = base.TaskSpec(
            name=f"{PREFIX}{env_id}", obs_dim=int(np.prod(probe.observation_space.shape)),
            critic_obs_dim=int(np.prod(probe.observation_space.shape)),
            action_dim=int(np.prod(probe.action_space.shape)), episode_length=config.episode_length,
            ctrl_dt=_ctrl_dt(probe), reward_terms=REWARD_TERMS,
        )
        self._action_shape = probe.action_space.shape
        low = probe.action_space.low.astype(np.float64).reshape(-1)
        high = probe.action_space.high.astype(np.float64).reshape(-1)
        self._center, self._half_range = (high + low) / 2.0, (high - low) / 2.0
        self._action_dtype = probe.action_space.dtype
        envs = [probe] + [_make_env(env_id, config.episode_length) for _ in range(num_envs - 1)]
        self.envs = gym.vector.SyncVectorEnv([lambda e=e: e for e in envs],
                                             autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
        self._seeds = [int(s) for s in np.random.SeedSequence(self.seed).generate_state(num_envs)]
        self._view: Any = None  # render-only MjData of render_scene, made on first use

    def _flat(self, obs: np.ndarray) -> np.ndarray:
        return np.asarray(obs, dtype=np.float32).reshape(self.num_envs, -1)

    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        obs, _ = self.envs.reset(seed=self._seeds)
        obs = self._flat(obs)
        return obs, obs.copy()

    def step(self, action: np.ndarray) -> base.StepOut:
        a = np.asarray(action, dtype=np.float64).reshape(self.num_envs, -1)
        a = np.clip(np.nan_to_num(a, nan=0.0), -1.0, 1.0)
        scaled = (self._center + self._half_range * a).astype(self._action_dtype)
        obs, reward, terminated, truncated, info = self.envs.step(scaled.reshape(self.num_envs, *self._action_shape))
        obs = self._flat(obs)
        next_obs = obs
        if "_final_obs" in info:  # same-step auto-reset: the ended envs' last observations
            ended = np.flatnonzero(info["_final_obs"])
            next_obs = obs.copy()
            next_obs[ended] = np.stack([np.asarray(info["final_obs"][i], np.float32).reshape(-1) for i in ended])
        term = np.asarray(terminated, dtype=bool)
        trunc = np.asarray(truncated, dtype=bool) & ~term
        reward = np.asarray(reward, dtype=np.float32)
        return base.StepOut(obs, obs.copy(), next_obs, next_obs.copy(), reward, term, trunc,
                            {"reward": reward.copy()})

    def render_scene(self, env: int = 0) -> tuple[Any, Any]:
        """(model, data) of env ``env`` for ``mujoco.Renderer`` (``unilab_jax.apps.play``): Gymnasium's MuJoCo
        environments only. A render-only MjData gets the env's full state and its kinematics (``mj_forward``),
        so rendering never touches the simulation."""
        import mujoco

        inner = self.envs.envs[env].unwrapped
        model, data = getattr(inner, "model", None), getattr(inner, "data", None)
        if not isinstance(model, mujoco.MjModel) or not isinstance(data, mujoco.MjData):
            raise NotImplementedError(f"{self.spec.name} is not a MuJoCo environment: no scene to render")
        if self._view is None or self._view.model is not model:
            self._view = mujoco.MjData(model)
        kind = mujoco.mjtState.mjSTATE_FULLPHYSICS
        state = np.empty(mujoco.mj_stateSize(model, kind))
        mujoco.mj_getState(model, data, state, kind)
        mujoco.mj_setState(model, self._view, state, kind)
        mujoco.mj_forward(model, self._view)
        return model, self._view

    def close(self) -> None:
        self.envs.close()


def make(env_id: str, config: GymConfig, num_envs: int, seed: int) -> GymTask:
    return GymTask(env_id, config, num_envs, seed)
