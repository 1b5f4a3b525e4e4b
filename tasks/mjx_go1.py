"""``go1_joystick_flat`` on MJX: the same MDP as the CPU task, stepped on the accelerator under ``jax.jit``.

The GPU-resident baseline (MuJoCo Playground / IsaacLab style) against which the heterogeneous runtime is
measured (``unilab_jax/training/mjx.py``, ``bench/time_to_target.py``). Everything that defines the task comes
from ``tasks/go1_joystick.py`` (configuration, model) and its math module ``tasks/go1_math.py``:

* Model: the same ``build_spec(config)`` MjSpec model (pyramidal cones, feet-only contacts, sensors),
  ``mjx.put_model(model, impl="jax")``; float32 throughout (the CPU task runs MuJoCo in float64 and
  hands float32 to the learner). One flag differs: ``mjDSBL_EULERDAMP`` is set when no dof has
  damping (see ``__init__``): a no-op for MuJoCo, but without it MJX's Euler step integrates a
  different acceleration than MuJoCo's.
* Physics: ``mjx.step`` ``ctrl_dt / sim_dt`` times per control step (a ``fori_loop``), ``jax.vmap`` over
  environments; each env has its own model fields (below); full float32 matrix products (``PRECISION``).
* Sensors: MJX computes every sensor type the task declares (gyro, velocimeter, accelerometer,
  framezaxis, framelinvel/angvel, framequat, framepos, contact "found", actuatorfrc), so observations
  and rewards read ``mjx.Data.sensordata`` through the CPU task's own ``go1_math.read_sensors``: foot contact is
  the contact sensor (a foot-floor contact with distance < 0), exactly as on the CPU.
* Observation, reward, termination and the per-step bookkeeping: ``go1_math.step_math`` on jax
  arrays (the shim picks the jax backend); reset poses ``floating_base.place_base``; command resampling
  ``go1_math.sample_command``. The random draws have the CPU task's distributions, from a jax key.
* Domain randomisation: the CPU task's parameters and distributions (``sample_dr`` returns a dict with
  the same keys as ``Go1JoystickFlat.dr``; ``reset(key, dr=task.dr)`` reuses a CPU task's draw), turned
  into per-env model fields (floor friction, dof frictionloss / armature, torso COM, body masses,
  ``qpos0``, servo gains for the optional motor strength) batched with ``vmap``, like Playground's
  ``randomize``; sampled once per env at reset.
  The default-pose offset also shifts the motor targets (see the CPU task's docstring). The optional action
  latency (``dr_action_delay``) is the CPU task's queue (``actuation.delay_actions``) in ``Go1MjxState.extra``.
* Hooks for variants (identities here): ``model_spec``, ``init_extra``, ``place``, ``extend_obs``, ``at_limit``,
  ``after_transition`` -- ``tasks/mjx_rough.py`` puts the rough-terrain task on them.
* Auto-reset: ended envs get a fresh random reset (new pose, velocities, command; ``mjx.forward`` for
  their sensors), ``reset_batch`` envs at a time (default ``num_envs / 16``, at least 32): their
  indices are gathered with ``nonzero``, reset and scattered back, in a ``while_loop`` that runs as
  many passes as needed (none on steps where no env ended). Playground instead resets every env to a
  cached first state (no ``mjx.forward`` at all); that would not be the CPU task's MDP.

Deviation: MuJoCo's divergence guard (``mj_checkPos/Vel/Acc`` every substep: non-finite or > 1e10)
is evaluated once per control step here, on the final ``qpos``/``qvel``/``qacc``; as on the CPU, such
envs (and any with a non-finite observation or reward) are truncated with zeroed outputs and reset.
"""

from __future__ import annotations

import contextlib
import io
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from tasks import actuation, base
from tasks import go1_joystick as gj
from tasks import go1_math as gm
from tasks.floating_base import place_base
from tasks.model_edits import sensor_index

with contextlib.redirect_stdout(io.StringIO()):  # mujoco.mjx prints a notice when the optional warp is absent
    from mujoco import mjx

MAX_VAL = 1e10  # MuJoCo's mjMAXVAL: larger positions / velocities / accelerations count as divergence
# Full float32 matrix products in the physics: JAX's GPU default (TF32 on Ampere and later) rounds to 10
# mantissa bits, which MuJoCo Playground warns destabilises training; the learner keeps JAX's default, as
# the heterogeneous runtime's learner does. Applied at trace time, whatever the global setting.
PRECISION = "highest"
DR_FIELDS = ("geom_friction", "dof_frictionloss", "dof_armature", "body_ipos", "body_mass", "qpos0",
             "actuator_gainprm", "actuator_biasprm")


class Go1MjxState(NamedTuple):
    """Batched state of ``num_envs`` environments (a pytree; every leaf has the env axis first)."""

    data: Any  # mjx.Data
    model_fields: dict  # per-env model fields (``DR_FIELDS``)
    pose_offset: jax.Array  # [M, nu] added to the motor targets
    info: dict  # command, last_act, feet_air_time, last_contact, swing_peak (``go1_math.step_math``)
    steps_until_next_cmd: jax.Array  # [M] int32
    steps: jax.Array  # [M] int32 control steps in the current episode
    obs: jax.Array  # [M, obs_dim] the observation the policy acts on (after auto-reset)
    critic_obs: jax.Array
    episode_return: jax.Array  # [M] running sums of the current episodes
    episode_length: jax.Array  # [M] int32
    key: jax.Array
    # per-env state of what the config adds: the action queue ("queue" [M, D, nu], "delay" [M]) with
    # ``dr_action_delay``; the rough variant's cells and curriculum sums (``tasks/mjx_rough.py``)
    extra: dict = {}


class MjxStepOut(NamedTuple):
    """``tasks.base.MjxStepOut`` plus the finished episodes' return/length (valid where an episode ended)."""

    obs: jax.Array
    critic_obs: jax.Array
    next_obs: jax.Array
    next_critic_obs: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    reward_terms: dict
    episode_return: jax.Array
    episode_length: jax.Array
    extras: dict = {}  # {name: [M]} per-episode metrics (``TaskSpec.episode_metrics``), read where episodes ended


# --------------------------------------------------------------------------------------------------
# Task-independent pieces (also used by ``tasks/mjx_walking.py``)
# --------------------------------------------------------------------------------------------------
def match_euler_damping(model: mujoco.MjModel) -> None:
    """Sets ``mjDSBL_EULERDAMP`` when no dof has damping (see ``Go1JoystickMjx.__init__``); with damping,
    MuJoCo and MJX both integrate the damping implicitly and nothing changes."""
    if not model.dof_damping.any():
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EULERDAMP


def physics_step(mjx_model: Any, nsub: int, fields: dict, data: Any, ctrl: jax.Array) -> Any:
    """One control step (``nsub`` ``mjx.step`` with ``ctrl`` held) of every env; ``fields`` are per-env
    model fields (leading env axis) replacing ``mjx_model``'s."""

    def one(f, d, u):
        model = mjx_model.tree_replace(f)
        return jax.lax.fori_loop(0, nsub, lambda _, x: mjx.step(model, x), d.replace(ctrl=u))

    with jax.default_matmul_precision(PRECISION):
        return jax.vmap(one)(fields, data, ctrl)


def forward(mjx_model: Any, template: Any, fields: dict, qpos: jax.Array, qvel: jax.Array, ctrl: jax.Array) -> Any:
    """Fresh data (``template``: time 0, zero warm start) at (qpos, qvel, ctrl) with ``mjx.forward`` run, per env."""

    def one(f, qp, qv, u):
        return mjx.forward(mjx_model.tree_replace(f), template.replace(qpos=qp, qvel=qv, ctrl=u))

    with jax.default_matmul_precision(PRECISION):
        return jax.vmap(one)(fields, qpos, qvel, ctrl)


def reset_in_batches(ended: jax.Array, carry: Any, key: jax.Array, batch: int, reset_rows: Any) -> Any:
    """Replaces the ``ended [n]`` rows of ``carry`` (a pytree, env axis first) with fresh episodes,
    ``batch`` envs per pass of a ``while_loop`` (their indices gathered with ``nonzero``, scattered back),
    so the reset work scales with the number of ended envs. ``reset_rows(k_reset, k_obs, rows)`` returns
    the pytree of ``carry``'s structure for env indices ``rows [batch]``."""
    n = ended.shape[0]
    drop = lambda full, part, idx: full.at[idx].set(part, mode="drop")  # idx == n: padding, dropped

    def one_pass(c):
        pending, carry, key = c
        key, k_reset, k_obs = jax.random.split(key, 3)
        idx = jnp.nonzero(pending, size=batch, fill_value=n)[0]
        part = reset_rows(k_reset, k_obs, jnp.minimum(idx, n - 1))
        carry = jax.tree_util.tree_map(lambda full, p: drop(full, p, idx), carry, part)
        return drop(pending, False, idx), carry, key

    return jax.lax.while_loop(lambda c: jnp.any(c[0]), one_pass, (ended, carry, key))[1]


def diverged(data: Any) -> jax.Array:
    """[M] MuJoCo's divergence guard on the final state: non-finite or > ``MAX_VAL`` qpos, qvel or qacc."""
    big = lambda x: jnp.any(~jnp.isfinite(x) | (jnp.abs(x) > MAX_VAL), axis=-1)
    return big(data.qpos) | big(data.qvel) | big(data.qacc)


def mask_unstable(data: Any, next_obs: jax.Array, next_cobs: jax.Array, reward: jax.Array, scaled: dict):
    """``diverged`` widened by non-finite outputs; returns (unstable [M], and the outputs zeroed where unstable)
    as ``finish_step``."""
    unstable = diverged(data)
    unstable |= ~(jnp.all(jnp.isfinite(next_obs), axis=1) & jnp.all(jnp.isfinite(next_cobs), axis=1)
                  & jnp.isfinite(reward))
    zero_where = lambda x: jnp.where(unstable.reshape(-1, *([1] * (x.ndim - 1))), 0.0, x)
    return (unstable, zero_where(next_obs), zero_where(next_cobs), zero_where(reward),
            {k: zero_where(v) for k, v in scaled.items()})


def finish_transition(state: Any, data: Any, steps: jax.Array, done: jax.Array, next_obs: jax.Array,
                      next_cobs: jax.Array, reward: jax.Array, scaled: dict, episode_length: int,
                      limit: jax.Array | None = None) -> MjxStepOut:
    """The end of a control step shared by the MJX tasks (before any auto-reset): ``mask_unstable``, the end
    flags (termination wins; divergence, ``steps >= episode_length`` and ``limit [M]`` -- a task's other limits,
    the rough variants' map edge -- truncate) and ``state``'s episode sums plus this step.
    The new state takes ``obs``, ``critic_obs``, ``episode_return`` and ``episode_length`` from the returned
    MjxStepOut."""
    unstable, next_obs, next_cobs, reward, scaled = mask_unstable(data, next_obs, next_cobs, reward, scaled)
    term = done & ~unstable
    trunc = ((steps >= episode_length) | unstable) & ~term
    if limit is not None:
        trunc |= limit & ~term
    return MjxStepOut(obs=next_obs, critic_obs=next_cobs, next_obs=next_obs, next_critic_obs=next_cobs, reward=reward,
                   terminated=term, truncated=trunc, reward_terms=scaled,
                   episode_return=state.episode_return + reward, episode_length=state.episode_length + 1)


def init_delay(dr: dict, depth: int, n: int, action_dim: int) -> dict:
    """The action queue's state (``tasks/actuation.py``): ``{"queue": zeros [n, depth, action_dim], "delay": [n]
    int32}`` from ``dr["action_delay"]`` (a CPU task's ``[n, 1]`` column or ``sample_delay``'s); ``{}`` when
    ``depth`` is 0 (latency off)."""
    if not depth:
        return {}
    delay = dr["action_delay"][:, 0] if "action_delay" in dr else jnp.zeros((n,))
    return {"queue": jnp.zeros((n, depth, action_dim)), "delay": jnp.round(delay).astype(jnp.int32)}


def sample_delay(config: Any, key: jax.Array, n: int) -> dict:
    """``{"action_delay": [n, 1]}``: per-env latencies U{lo, ..., hi} control steps (the CPU task's
    ``actuation.sample_delays``), or ``{}`` where the CPU task draws none (latency or randomisation off)."""
    lo, hi = (int(b) for b in config.dr_action_delay)
    if not (config.domain_randomization and hi > 0):
        return {}
    return {"action_delay": jax.random.randint(key, (n, 1), lo, hi + 1).astype(jnp.float32)}


def delayed(state: Any, a: jax.Array) -> tuple[jax.Array, Any]:
    """(the action the motors get, ``state`` with its queue advanced): ``actuation.delay_actions`` on
    ``state.extra``'s queue; ``a`` itself without one."""
    if "queue" not in state.extra:
        return a, state
    applied, queue = actuation.delay_actions(state.extra["queue"], a, state.extra["delay"])
    return applied, state._replace(extra={**state.extra, "queue": queue})


def restart_queue(extra: dict, ended: jax.Array) -> dict:
    """``extra`` with the ``ended`` envs' action queues emptied (zero actions: the default pose), as at a reset."""
    if "queue" not in extra:
        return extra
    return {**extra, "queue": jnp.where(ended[:, None, None], 0.0, extra["queue"])}


def restart_episodes(state: Any, ended: jax.Array, key: jax.Array, **fresh: Any) -> Any:
    """``state`` with the ``ended`` envs' step counter and episode sums zeroed, the new ``key``, and ``fresh``
    (the fields the auto-reset rewrote: data, info, obs, ...) replaced."""
    return state._replace(steps=jnp.where(ended, 0, state.steps),
                          episode_return=jnp.where(ended, 0.0, state.episode_return),
                          episode_length=jnp.where(ended, 0, state.episode_length), key=key, **fresh)


class MjxHooks:
    """What the rough variants (``tasks/mjx_rough.py``) override in the MJX tasks (``Go1JoystickMjx``,
    ``mjx_walking.WalkingMjx``); on flat ground they keep the action queue and change nothing else. The task sets
    ``config`` and ``spec``."""

    def init_extra(self, key: jax.Array, dr: dict, n: int) -> dict:
        """The state's ``extra`` at the first reset: the action queue (``init_delay``)."""
        return init_delay(dr, self.config.dr_action_delay[1], n, self.spec.action_dim)

    def place(self, qpos: jax.Array, extra: dict) -> jax.Array:
        """New episodes' ``qpos [n, nq]`` moved where their envs start (``extra``: those envs' rows)."""
        return qpos

    def extend_obs(self, data: Any, obs: jax.Array, critic_obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(obs, critic_obs) with what a variant appends (the rough variant's height scan)."""
        return obs, critic_obs

    def at_limit(self, data: Any) -> jax.Array | None:
        """[M] truncations besides the time limit (the rough variant's map edge); None: none."""
        return None

    def after_transition(self, before: Any, state: Any, out: MjxStepOut, ended: jax.Array,
                         key: jax.Array) -> tuple[Any, MjxStepOut]:
        """(state, out) after ``transition`` and before the auto-reset of the ``ended`` envs (``before``: the state
        the step started from): here the ended envs' action queues are emptied."""
        return state._replace(extra=restart_queue(state.extra, ended)), out


class Go1JoystickMjx(MjxHooks):
    """``reset(key, dr=None) -> Go1MjxState``; ``step(state, action) -> (Go1MjxState, MjxStepOut)``; pure and
    jit-able (call them inside ``jax.jit``); ``spec`` as the CPU task's."""

    def __init__(self, config: gj.Go1JoystickConfig, num_envs: int, reset_batch: int = 0):
        c = config
        nsub = round(c.ctrl_dt / c.sim_dt)
        if nsub < 1 or abs(nsub * c.sim_dt - c.ctrl_dt) > 1e-9:
            raise ValueError(f"ctrl_dt {c.ctrl_dt} must be a multiple of sim_dt {c.sim_dt}")
        if num_envs <= 0:
            raise ValueError(f"num_envs must be positive, got {num_envs}")
        self.config, self.num_envs, self.nsub, self.dt = c, int(num_envs), nsub, c.ctrl_dt
        self.reset_batch = int(reset_batch or min(num_envs, max(32, math.ceil(num_envs / 16))))
        self.model = self.model_spec().compile()
        m = self.model
        # MuJoCo's Euler integrates the solver's qacc unless some dof has damping; MJX's re-solves
        # M qacc = qfrc_smooth + qfrc_constraint whenever eulerdamp is on, which with the 1-iteration
        # solver is not the solver's qacc (measured: 4.5 rad/s apart after one substep). Disabling
        # eulerdamp when no dof has damping, a no-op for MuJoCo, makes MJX integrate what MuJoCo integrates.
        match_euler_damping(m)
        self.mjx_model = mjx.put_model(m, impl="jax")
        self._template = mjx.make_data(self.mjx_model)
        self.sensor_index = sensor_index(m)
        self.floor_id, self.torso_id = m.geom("floor").id, m.body("trunk").id
        init_qpos = np.array(m.key("home").qpos)
        lowers, uppers = m.jnt_range[1:].T
        f32 = lambda x: jnp.asarray(np.asarray(x, dtype=np.float32))
        self.init_qpos = f32(init_qpos)
        self.consts = {"default_pose": f32(init_qpos[7:]), "pose_weight": f32(gm.POSE_WEIGHT),
                       "soft_lower": f32(lowers * c.soft_joint_pos_limit_factor),
                       "soft_upper": f32(uppers * c.soft_joint_pos_limit_factor)}
        self.noise_scale = f32(gm.noise_scales(c))
        self.scales = gj.reward_scales(c)
        self._cmd_a, self._cmd_b = f32(c.command_a), f32(c.command_b)
        nb = m.nbody - 1
        self.dr_dims = {"armature_scale": 12, "com_offset": 3, "default_pose_offset": 12, "floor_friction": 1,
                        "frictionloss_scale": 12, "mass_scale": nb, "motor_strength": m.nu, "torso_mass_delta": 1}
        self.spec = base.TaskSpec(
            name="go1_joystick_flat", obs_dim=gm.OBS_DIM, critic_obs_dim=gm.CRITIC_OBS_DIM, action_dim=m.nu,
            episode_length=c.episode_length, ctrl_dt=c.ctrl_dt, reward_terms=gm.REWARD_TERMS,
            privileged_dim=sum(self.dr_dims.values()),
        )

    def model_spec(self) -> mujoco.MjSpec:
        """The CPU task's model (the rough variant's adds the terrain)."""
        return gj.build_spec(self.config)

    # ---- domain randomisation -----------------------------------------------------------------
    def sample_dr(self, key: jax.Array, n: int) -> dict[str, jax.Array]:
        """Per-env DR parameters with the CPU task's keys and distributions (``Go1JoystickFlat.dr``; latencies
        ``action_delay`` from ``key``'s fold 1, so the other draws stay as without them)."""
        return {**self._sample_model_dr(key, n), **sample_delay(self.config, jax.random.fold_in(key, 1), n)}

    def _sample_model_dr(self, key: jax.Array, n: int) -> dict[str, jax.Array]:
        c = self.config
        if not c.domain_randomization:
            return {"floor_friction": jnp.full((n, 1), 0.6), "frictionloss_scale": jnp.ones((n, 12)),
                    "armature_scale": jnp.ones((n, 12)), "com_offset": jnp.zeros((n, 3)),
                    "mass_scale": jnp.ones((n, self.dr_dims["mass_scale"])), "torso_mass_delta": jnp.zeros((n, 1)),
                    "default_pose_offset": jnp.zeros((n, 12)), "motor_strength": jnp.ones((n, 12))}
        ks = jax.random.split(key, 8)
        u = lambda k, shape, lo, hi: jax.random.uniform(k, shape, jnp.float32, lo, hi)
        lo, hi = c.dr_motor_strength
        return {
            "motor_strength": u(ks[7], (n, 12), lo, hi) if hi > lo else jnp.full((n, 12), lo, jnp.float32),
            "floor_friction": u(ks[0], (n, 1), *c.dr_floor_friction),
            "frictionloss_scale": u(ks[1], (n, 12), *c.dr_frictionloss_scale),
            "armature_scale": u(ks[2], (n, 12), *c.dr_armature_scale),
            "com_offset": u(ks[3], (n, 3), -c.dr_com_offset, c.dr_com_offset),
            "mass_scale": u(ks[4], (n, self.dr_dims["mass_scale"]), *c.dr_link_mass_scale),
            "torso_mass_delta": u(ks[5], (n, 1), -c.dr_torso_mass_delta, c.dr_torso_mass_delta),
            "default_pose_offset": u(ks[6], (n, 12), -c.dr_default_pose_offset, c.dr_default_pose_offset),
        }

    def model_fields(self, dr: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """The per-env model fields of ``dr`` (the CPU task's ``_apply_dr``, batched)."""
        m = self.mjx_model
        n = dr["floor_friction"].shape[0]
        tile = lambda x: jnp.broadcast_to(x, (n, *x.shape))
        friction = tile(m.geom_friction).at[:, self.floor_id, 0].set(dr["floor_friction"][:, 0])
        floss = jnp.concatenate([tile(m.dof_frictionloss[:6]), m.dof_frictionloss[6:] * dr["frictionloss_scale"]],
                                axis=1)
        armature = jnp.concatenate([tile(m.dof_armature[:6]), m.dof_armature[6:] * dr["armature_scale"]], axis=1)
        ipos = tile(m.body_ipos).at[:, self.torso_id].add(dr["com_offset"])
        mass = jnp.concatenate([tile(m.body_mass[:1]), m.body_mass[1:] * dr["mass_scale"]], axis=1)
        mass = mass.at[:, self.torso_id].add(dr["torso_mass_delta"][:, 0])
        qpos0 = tile(m.qpos0).at[:, 7:].add(dr["default_pose_offset"])
        # Motor strength scales each position servo's Kp (gain) and its -Kp / -Kd bias terms.
        strength = dr["motor_strength"]
        gain = tile(m.actuator_gainprm).at[:, :, 0].multiply(strength)
        bias = tile(m.actuator_biasprm).at[:, :, 1:3].multiply(strength[:, :, None])
        return dict(zip(DR_FIELDS, (friction, floss, armature, ipos, mass, qpos0, gain, bias)))

    # ---- physics ------------------------------------------------------------------------------
    def physics_step(self, fields: dict, data: Any, ctrl: jax.Array) -> Any:
        """One control step (``nsub`` ``mjx.step`` with ``ctrl`` held) of every env."""
        return physics_step(self.mjx_model, self.nsub, fields, data, ctrl)

    def forward(self, fields: dict, qpos: jax.Array, qvel: jax.Array, ctrl: jax.Array) -> Any:
        """Fresh data (time 0, zero warm start) at (qpos, qvel, ctrl) with ``mjx.forward`` run, per env."""
        return forward(self.mjx_model, self._template, fields, qpos, qvel, ctrl)

    # ---- task ---------------------------------------------------------------------------------
    def _sensors(self, data: Any) -> dict:
        return gm.read_sensors(data.sensordata, self.sensor_index, self.model.nu)

    def base_velocity(self, state: Go1MjxState) -> jax.Array:
        """[M, 3] measured body-frame (vx, vy) and yaw rate, as the CPU task's ``base_velocity`` (walking metric)."""
        s = self._sensors(state.data)
        return jnp.concatenate([s["local_linvel"][:, :2], s["gyro"][:, 2:3]], axis=1)

    def _noise(self, key: jax.Array, n: int) -> jax.Array:
        return jax.random.uniform(key, (n, self.noise_scale.shape[0]), jnp.float32, -1.0, 1.0) * self.noise_scale

    def _exp_steps(self, key: jax.Array, n: int) -> jax.Array:
        t = jax.random.exponential(key, (n,), jnp.float32) * self.config.command_resample_mean_s
        return jnp.round(t / self.dt).astype(jnp.int32)

    def _reset_draws(self, key: jax.Array, fields: dict, pose_offset: jax.Array,
                     extra: dict) -> tuple[Any, dict, jax.Array]:
        """New episodes for the envs of these rows (``extra``: their ``Go1MjxState.extra``): (data after
        ``mjx.forward``, zeroed info with a new command, steps until the next command)."""
        c, n = self.config, pose_offset.shape[0]
        ks = jax.random.split(key, 5)
        u = lambda k, shape, lo, hi: jax.random.uniform(k, shape, jnp.float32, lo, hi)
        qpos, qvel = place_base(self.init_qpos, u(ks[0], (n, 2), -c.reset_xy, c.reset_xy),
                                   u(ks[1], (n,), -c.reset_yaw, c.reset_yaw),
                                   u(ks[2], (n, 6), -c.reset_base_vel, c.reset_base_vel), self.model.nv)
        data = self.forward(fields, self.place(qpos, extra), qvel, self.consts["default_pose"] + pose_offset)
        nu = self.model.nu
        info = {"command": u(ks[3], (n, 3), -self._cmd_a, self._cmd_a), "last_act": jnp.zeros((n, nu)),
                "feet_air_time": jnp.zeros((n, 4)), "last_contact": jnp.zeros((n, 4), bool),
                "swing_peak": jnp.zeros((n, 4))}
        return data, info, self._exp_steps(ks[4], n)

    def _observe(self, data: Any, info: dict, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        return self.extend_obs(data, *gm.observe(
            self._sensors(data), data.qpos[:, 7:], data.qvel[:, 6:], info["last_act"], info["command"],
            info["last_contact"], info["feet_air_time"], self.consts["default_pose"],
            self._noise(key, data.qpos.shape[0])))

    def _reset_ended(self, ended, state, data, info, until, obs, cobs, key):
        """Fresh episodes for the ``ended`` envs, ``reset_batch`` of them per pass (``reset_in_batches``),
        so the reset work scales with the number of ended envs instead of ``mjx.forward`` on the whole
        batch at every step."""

        def reset_rows(k_reset, k_obs, rows):
            fields, extra = jax.tree_util.tree_map(lambda x: x[rows], (state.model_fields, state.extra))
            r_data, r_info, r_until = self._reset_draws(k_reset, fields, state.pose_offset[rows], extra)
            r_obs, r_cobs = self._observe(r_data, r_info, k_obs)
            return r_data, r_info, r_until, r_obs, r_cobs

        return reset_in_batches(ended, (data, info, until, obs, cobs), key, self.reset_batch, reset_rows)

    def reset(self, key: jax.Array, dr: dict | None = None) -> Go1MjxState:
        """Every env at the start of an episode; ``dr`` (numpy or jax, the CPU task's keys) fixes the
        domain-randomisation draw, otherwise it is sampled from ``key``."""
        n = self.num_envs
        k_dr, k_reset, k_obs, k_state = jax.random.split(key, 4)
        dr = self.sample_dr(k_dr, n) if dr is None else {k: jnp.asarray(v, jnp.float32) for k, v in dr.items()}
        fields = self.model_fields(dr)
        offset = dr["default_pose_offset"] if self.config.dr_pose_offset_on_targets else jnp.zeros((n, 12))
        extra = self.init_extra(jax.random.fold_in(k_dr, 2), dr, n)
        data, info, until = self._reset_draws(k_reset, fields, offset, extra)
        obs, cobs = self._observe(data, info, k_obs)
        return Go1MjxState(data=data, model_fields=fields, pose_offset=offset, info=info, steps_until_next_cmd=until,
                           steps=jnp.zeros((n,), jnp.int32), obs=obs, critic_obs=cobs,
                           episode_return=jnp.zeros((n,)), episode_length=jnp.zeros((n,), jnp.int32), key=k_state,
                           extra=extra)

    def step(self, state: Go1MjxState, action: jax.Array) -> tuple[Go1MjxState, MjxStepOut]:
        """One control step of every env (``action [M, nu]`` clipped to [-1, 1], NaN -> 0; the motors get it
        ``extra["delay"]`` steps late with ``dr_action_delay``); ended envs auto-reset (``MjxStepOut.obs`` after
        the reset, ``next_obs`` before it)."""
        a = jnp.clip(jnp.nan_to_num(action.astype(jnp.float32), nan=0.0), -1.0, 1.0)
        applied, state = delayed(state, a)
        ctrl = self.consts["default_pose"] + state.pose_offset + applied * self.config.action_scale
        return self.after_physics(state, self.physics_step(state.model_fields, state.data, ctrl), a)

    def after_physics(self, state: Go1MjxState, data: Any, a: jax.Array) -> tuple[Go1MjxState, MjxStepOut]:
        """The rest of ``step`` given the post-physics ``data`` and the clipped action ``a``: ``transition``,
        then fresh episodes for the envs that ended."""
        st, out = self.transition(state, data, a)
        ended = out.terminated | out.truncated
        key, k_reset = jax.random.split(st.key)
        st, out = self.after_transition(state, st, out, ended, jax.random.fold_in(k_reset, 1))
        data, info, until, obs, cobs = self._reset_ended(ended, st, st.data, st.info, st.steps_until_next_cmd,
                                                         st.obs, st.critic_obs, k_reset)
        new_state = restart_episodes(st, ended, key, data=data, info=info, steps_until_next_cmd=until, obs=obs,
                                     critic_obs=cobs)
        return new_state, out._replace(obs=obs, critic_obs=cobs)

    def transition(self, state: Go1MjxState, data: Any, a: jax.Array) -> tuple[Go1MjxState, MjxStepOut]:
        """Observation, reward, end flags and bookkeeping of a control step from the post-physics ``data``,
        before any auto-reset (the returned state's and MjxStepOut's ``obs`` are ``next_obs``; ``steps`` and the
        episode sums include this step). The parity tests call it on data from ``forward``."""
        c, n = self.config, self.num_envs
        key, k_noise, k_cmd = jax.random.split(state.key, 3)
        next_obs, next_cobs, done, scaled, reward, updated = gm.step_math(
            self._sensors(data), data.qpos[:, 7:], data.qvel[:, 6:], a, state.info, self._noise(k_noise, n),
            self.consts, c, self.scales, self.dt)
        next_obs, next_cobs = self.extend_obs(data, next_obs, next_cobs)
        # Command resampling (the CPU task's rule and draws).
        kc = jax.random.split(k_cmd, 4)
        until = state.steps_until_next_cmd - 1
        due = until <= 0
        new_cmd = gm.sample_command(
            state.info["command"], jax.random.uniform(kc[0], (n, 3), jnp.float32, -self._cmd_a, self._cmd_a),
            jax.random.uniform(kc[1], (n, 3)) < self._cmd_b, jax.random.uniform(kc[2], (n, 3)) < 0.5)
        info = {**updated, "command": jnp.where(due[:, None], new_cmd, state.info["command"])}
        until = jnp.where(due, self._exp_steps(kc[3], n), until)
        steps = state.steps + 1
        # Divergence and non-finite outputs: truncate with zeroed outputs (the CPU task's finish_step).
        out = finish_transition(state, data, steps, done, next_obs, next_cobs, reward, scaled, c.episode_length,
                                self.at_limit(data))
        new_state = state._replace(data=data, info=info, steps_until_next_cmd=until, steps=steps, obs=out.obs,
                                   critic_obs=out.critic_obs, episode_return=out.episode_return,
                                   episode_length=out.episode_length, key=key)
        return new_state, out


def make(config: gj.Go1JoystickConfig, num_envs: int, reset_batch: int = 0) -> Go1JoystickMjx:
    return Go1JoystickMjx(config, num_envs, reset_batch)
