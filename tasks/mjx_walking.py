"""The gait-phase walking tasks (``go2_joystick_flat``, ``g1_walk_flat``) on MJX, stepped under ``jax.jit``.

The walking counterpart of ``tasks/mjx_go1.py`` (same design, its task-independent pieces imported from
there): one ``WalkingMjx`` class runs any ``walking.WalkingTask`` subclass, built from a one-env instance
of the CPU task (the *template*) that supplies everything that defines the task:

* Model: the CPU task's ``build_spec(config)`` MjSpec model, ``mjx.put_model(model, impl="jax")``, float32,
  ``mjDSBL_EULERDAMP`` as in ``mjx_go1`` (both walking tasks have joint damping -- their Kd -- so MuJoCo and
  MJX both integrate it implicitly and the flag stays off). One edit, to the sensors only: MJX has no
  contact sensor with *body* matching (G1's foot contact sensors are per ankle body, each foot touching
  through four spheres). Such a sensor is re-pointed at the body's first colliding geom and one sensor per
  further geom of the body is appended after the CPU model's sensors; ``cpu_sensordata`` adds them back
  into the CPU layout (a foot's "found" count is the sum of its spheres'), so every address the CPU task
  reads is unchanged. Physics is untouched.
* Physics: ``mjx_go1.physics_step`` (``ctrl_dt / sim_dt`` ``mjx.step`` in a ``fori_loop``, ``vmap`` over envs,
  per-env model fields, ``PRECISION`` "highest"); ``mjx_go1.forward`` for resets and the parity tests.
  MJX ignores MuJoCo 4's polynomial joint damping (``dof_dampingpoly``); the walking tasks' Kd is linear
  (``walking.position_servos``), and a model with polynomial damping is refused.
* Observation, reward, termination: ``walking.read_sensors`` on ``mjx.Data.sensordata`` and
  ``walking.step_math`` on jax arrays, calling the template's own ``reward_terms`` / ``critic_extra`` hooks
  (shim-written, reading only constants from the template). The gait clock is a table of the CPU task's
  own float64 phases per episode step (``walking.gait_phase(steps * dt)``; stance from the float64 phase):
  float32 phases disagree with float64 about stance exactly at the phase boundaries (G1: 20 of 1001
  steps); steps past ``episode_length`` (never reached: that step truncates) read the last row.
* Resets: the CPU task's distribution (``floating_base.place_base`` of U(+-reset_xy), U(+-reset_yaw),
  U(+-reset_base_vel) draws, the home pose at its standing height, servo targets at the default pose, a
  command U(command_low, command_high) per episode, last action 0, step 0) from a jax key; auto-reset of
  ended envs with ``mjx_go1.reset_in_batches``.
* Pushes: as the CPU task, every ``push_interval_s`` of episode time a non-terminated env's base linear
  velocity (world frame) gets + U(+-push_vel), after the observation is taken (seen from the next step on).
* Domain randomisation: per task (``DR``), the CPU task's ``sample_dr`` keys and distributions from a jax
  key (``reset(key, dr=task.dr)`` reuses a CPU draw) and ``randomize_model`` as batched model fields --
  Go2: servo Kp (``actuator_gainprm[:, 0]`` and ``actuator_biasprm[:, 1]``), Kd (``dof_damping`` of the
  actuated dofs), base mass and base COM x; G1: floor friction, every body's mass, torso COM. The actuation's,
  as the CPU task's and only where it draws them: motor strength (``dr_motor_strength``: each servo's Kp and Kd
  times a per-env, per-motor factor) and action latency (``dr_action_delay``: the queue of
  ``mjx_go1.delayed`` in ``WalkingMjxState.extra``).
* Variants: the hooks of ``mjx_go1.MjxHooks`` (``tasks/mjx_rough.py``: the rough tasks).
* Divergence: ``mjx_go1.finish_transition`` / ``mask_unstable`` (MuJoCo's guard evaluated once per control
  step, on the final state): such envs are truncated with zeroed outputs and reset, as on the CPU.

Deviations from the CPU task: float32 physics and observation math (MuJoCo runs in float64); random draws
come from jax keys (same distributions, different streams); the divergence check runs on the final substep
only (``mjx_go1``'s deviation). The CPU task's counters (``unstable_count``, ``push_count``) and its
``extrinsics`` / ``base_velocity()`` are not kept.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from tasks import g1_walk, go2_joystick, walking
from tasks import mjx_go1 as mg
from tasks.floating_base import place_base
from tasks.mjx_go1 import MjxStepOut, mjx

__all__ = ["DR", "WalkingMjxState", "MjxStepOut", "WalkingMjx", "make"]


class WalkingMjxState(NamedTuple):
    """Batched state of ``num_envs`` walking environments (a pytree; every leaf has the env axis first)."""

    data: Any  # mjx.Data
    model_fields: dict  # per-env model fields (the task's ``DR`` fields)
    info: dict  # command [M, 3], last_act [M, n] (the per-env episode state ``walking.step_math`` reads)
    steps: jax.Array  # [M] int32 control steps in the current episode
    obs: jax.Array  # [M, obs_dim] the observation the policy acts on (after auto-reset)
    critic_obs: jax.Array
    episode_return: jax.Array  # [M] running sums of the current episodes
    episode_length: jax.Array  # [M] int32
    key: jax.Array
    extra: dict = {}  # per-env state of what the config adds (``mjx_go1.Go1MjxState.extra``)


# --------------------------------------------------------------------------------------------------
# Domain randomisation per task: the CPU task's ``sample_dr`` / ``randomize_model``, batched in jax
# --------------------------------------------------------------------------------------------------
class TaskDR(NamedTuple):
    fields: tuple[str, ...]  # the per-env model fields
    sample: Callable  # (env, key, n) -> {name: [n, k]} (the CPU task's ``dr`` keys)
    model_fields: Callable  # (env, dr) -> {field: [n, ...]}


def _uniform(key, shape, lo, hi):
    return jax.random.uniform(key, shape, jnp.float32, lo, hi)


def _tile(x, n):
    return jnp.broadcast_to(x, (n, *x.shape))


def _go2_sample(env: WalkingMjx, key: jax.Array, n: int) -> dict:
    c, nu = env.config, env.model.nu
    if not c.domain_randomization:
        return {"base_com_x": jnp.zeros((n, 1)), "base_mass_delta": jnp.zeros((n, 1)), "kd_scale": jnp.ones((n, nu)),
                "kp_scale": jnp.ones((n, nu))}
    ks = jax.random.split(key, 4)
    return {"base_com_x": _uniform(ks[0], (n, 1), -c.dr_base_com_x, c.dr_base_com_x),
            "base_mass_delta": _uniform(ks[1], (n, 1), -c.dr_base_mass_delta, c.dr_base_mass_delta),
            "kd_scale": _uniform(ks[2], (n, nu), *c.dr_kd_scale), "kp_scale": _uniform(ks[3], (n, nu), *c.dr_kp_scale)}


def _go2_fields(env: WalkingMjx, dr: dict) -> dict:
    """``Go2JoystickFlat.randomize_model``, batched."""
    c, m, n = env.config, env.mjx_model, dr["kp_scale"].shape[0]
    kp = c.kp * dr["kp_scale"]
    b = env.model.body("base").id
    return {
        "actuator_gainprm": _tile(m.actuator_gainprm, n).at[:, :, 0].set(kp),
        "actuator_biasprm": _tile(m.actuator_biasprm, n).at[:, :, 1].set(-kp),
        "dof_damping": _tile(m.dof_damping, n).at[:, env.template._act_vadr].set(c.kd * dr["kd_scale"]),
        "body_mass": _tile(m.body_mass, n).at[:, b].add(dr["base_mass_delta"][:, 0]),
        "body_ipos": _tile(m.body_ipos, n).at[:, b, 0].add(dr["base_com_x"][:, 0]),
    }


def _g1_sample(env: WalkingMjx, key: jax.Array, n: int) -> dict:
    c, nb = env.config, env.model.nbody - 1
    if not c.domain_randomization:
        friction = float(env.model.geom_friction[env.model.geom("floor").id, 0])
        return {"com_offset": jnp.zeros((n, 3)), "floor_friction": jnp.full((n, 1), friction),
                "mass_scale": jnp.ones((n, nb))}
    ks = jax.random.split(key, 3)
    return {"com_offset": _uniform(ks[0], (n, 3), -c.dr_torso_com, c.dr_torso_com),
            "floor_friction": _uniform(ks[1], (n, 1), *c.dr_floor_friction),
            "mass_scale": _uniform(ks[2], (n, nb), *c.dr_mass_scale)}


def _g1_fields(env: WalkingMjx, dr: dict) -> dict:
    """``G1WalkFlat.randomize_model``, batched."""
    m, n = env.mjx_model, dr["mass_scale"].shape[0]
    floor, torso = env.model.geom("floor").id, env.model.body("torso_link").id
    mass = jnp.concatenate([_tile(m.body_mass[:1], n), m.body_mass[1:] * dr["mass_scale"]], axis=1)
    return {
        "geom_friction": _tile(m.geom_friction, n).at[:, floor, 0].set(dr["floor_friction"][:, 0]),
        "body_mass": mass,
        "body_ipos": _tile(m.body_ipos, n).at[:, torso].add(dr["com_offset"]),
    }


DR = {
    go2_joystick.Go2JoystickFlat: TaskDR(("actuator_gainprm", "actuator_biasprm", "dof_damping", "body_mass",
                                          "body_ipos"), _go2_sample, _go2_fields),
    g1_walk.G1WalkFlat: TaskDR(("geom_friction", "body_mass", "body_ipos"), _g1_sample, _g1_fields),
}
TASK_CLASSES = {cls.NAME: cls for cls in DR}
_CONFIG_CLASSES = {go2_joystick.Go2JoystickConfig: go2_joystick.Go2JoystickFlat,
                   g1_walk.G1WalkConfig: g1_walk.G1WalkFlat}


# --------------------------------------------------------------------------------------------------
# Model: body-matching contact sensors split per geom
# --------------------------------------------------------------------------------------------------
def split_body_contact_sensors(spec: mujoco.MjSpec) -> list[tuple[str, list[str]]]:
    """Re-points every contact sensor with body matching at the body's first colliding geom and appends one
    sensor per further colliding geom (after every existing sensor, so the existing addresses stay);
    returns [(sensor name, [appended sensor names])]. Unnamed geoms get a name."""
    S, Ob = mujoco.mjtSensor, mujoco.mjtObj
    split = []
    for sensor in list(spec.sensors):
        if sensor.type != S.mjSENS_CONTACT or sensor.objtype != Ob.mjOBJ_BODY:
            continue
        body = spec.body(sensor.objname)
        geoms = [g for g in body.geoms if g.contype or g.conaffinity]
        if not geoms:
            raise ValueError(f"contact sensor {sensor.name!r}: body {sensor.objname!r} has no colliding geom")
        for k, g in enumerate(geoms):
            if not g.name:
                g.name = f"{body.name}_contact{k}"
        extra = []
        for g in geoms[1:]:
            name = f"{sensor.name}__{g.name}"
            spec.add_sensor(name=name, type=S.mjSENS_CONTACT, objtype=Ob.mjOBJ_GEOM, objname=g.name,
                            reftype=sensor.reftype, refname=sensor.refname, intprm=list(sensor.intprm))
            extra.append(name)
        sensor.objtype, sensor.objname = Ob.mjOBJ_GEOM, geoms[0].name
        split.append((sensor.name, extra))
    return split


# --------------------------------------------------------------------------------------------------
# The environment
# --------------------------------------------------------------------------------------------------
def task_dr(task_cls: type) -> TaskDR:
    """The domain randomisation of ``task_cls`` or of the flat task it extends (the rough tasks: their flat one's)."""
    for cls in task_cls.__mro__:
        if cls in DR:
            return DR[cls]
    raise ValueError(f"{task_cls.__name__} has no MJX domain randomisation; known: {sorted(TASK_CLASSES)}")


class WalkingMjx(mg.MjxHooks):
    """``reset(key, dr=None) -> WalkingMjxState``; ``step(state, action) -> (WalkingMjxState, MjxStepOut)``; pure
    and jit-able; ``spec`` as the CPU task's. ``template`` is the one-env CPU task it is built from (a subclass of
    a task in ``DR``: the rough tasks' template brings the terrain, ``tasks/mjx_rough.py``)."""

    def __init__(self, task_cls: type[walking.WalkingTask], config: walking.WalkingConfig, num_envs: int,
                 reset_batch: int = 0):
        self.dr_spec = task_dr(task_cls)
        if num_envs <= 0:
            raise ValueError(f"num_envs must be positive, got {num_envs}")
        self.template = t = task_cls(config, 1, 0)  # constants, hooks and the compiled CPU model
        t.close()
        c = self.config = config
        self.num_envs, self.dt, self.spec = int(num_envs), t.dt, t.spec
        self.nsub = round(c.ctrl_dt / c.sim_dt)
        self.reset_batch = int(reset_batch or min(num_envs, max(32, math.ceil(num_envs / 16))))
        self.model = t.model  # the CPU task's model (sensor layout of ``cpu_sensordata``)
        spec = t.build_spec(c)
        self._contact_split = split_body_contact_sensors(spec)
        m = self.mjx_host_model = spec.compile()
        mg.match_euler_damping(m)
        for i in range(self.model.nsensor):  # the CPU layout is a prefix of the MJX model's
            name = self.model.sensor(i).name
            if m.sensor(name).adr[0] != self.model.sensor_adr[i] or m.sensor(name).dim[0] != self.model.sensor_dim[i]:
                raise AssertionError(f"sensor {name!r} moved in the MJX model")
        self._split_adr = [(int(m.sensor(name).adr[0]), [int(m.sensor(e).adr[0]) for e in extra])
                           for name, extra in self._contact_split]
        self.mjx_model = mjx.put_model(m, impl="jax")
        if np.any(getattr(m, "dof_dampingpoly", 0.0)):
            raise ValueError(f"{task_cls.__name__}: MJX ignores polynomial joint damping (dof_dampingpoly)")
        self._template_data = mjx.make_data(self.mjx_model)
        self.layout = t.sensor_layout()
        f32 = lambda x: jnp.asarray(np.asarray(x, dtype=np.float32))
        self.init_qpos, self.default_ctrl = f32(t.init_qpos), f32(t.default_ctrl)
        self.policy_idx = np.asarray(t.policy_idx)
        self.noise_scale = f32(t._noise_scale)
        # The CPU task's float64 gait clock per episode step (0 .. episode_length).
        phase = walking.gait_phase(np.arange(c.episode_length + 1) * self.dt, c.gait_frequency, t.gait_offsets)
        self.phase_table, self.stance_table = f32(phase), jnp.asarray(walking.stance_mask(phase, c.stance_fraction))
        self._cmd_low, self._cmd_high = f32(c.command_low), f32(c.command_high)
        self._push_every = t._push_every

    # ---- domain randomisation -----------------------------------------------------------------
    def sample_dr(self, key: jax.Array, n: int) -> dict[str, jax.Array]:
        """Per-env DR parameters with the CPU task's keys and distributions (``task.dr``; the actuation's,
        ``motor_strength`` and ``action_delay``, only where the CPU task draws them, from folds of ``key``)."""
        c, dr = self.config, self.dr_spec.sample(self, key, n)
        lo, hi = c.dr_motor_strength
        if c.domain_randomization and (lo, hi) != (1.0, 1.0):
            dr["motor_strength"] = _uniform(jax.random.fold_in(key, 1), (n, self.model.nu), lo, hi)
        return {**dr, **mg.sample_delay(c, jax.random.fold_in(key, 2), n)}

    def model_fields(self, dr: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """The per-env model fields of ``dr`` (the CPU task's ``randomize_model``, batched, then the motor strength:
        each servo's Kp and Kd times its factor)."""
        fields = self.dr_spec.model_fields(self, dr)
        if "motor_strength" not in dr:
            return fields
        m, strength = self.mjx_model, dr["motor_strength"]
        n, vadr = strength.shape[0], self.template._act_vadr
        gain = fields.get("actuator_gainprm", _tile(m.actuator_gainprm, n))
        bias = fields.get("actuator_biasprm", _tile(m.actuator_biasprm, n))
        damping = fields.get("dof_damping", _tile(m.dof_damping, n))
        return {**fields, "actuator_gainprm": gain.at[:, :, 0].multiply(strength),
                "actuator_biasprm": bias.at[:, :, 1].multiply(strength),
                "dof_damping": damping.at[:, vadr].multiply(strength)}

    # ---- physics ------------------------------------------------------------------------------
    def physics_step(self, fields: dict, data: Any, ctrl: jax.Array) -> Any:
        return mg.physics_step(self.mjx_model, self.nsub, fields, data, ctrl)

    def forward(self, fields: dict, qpos: jax.Array, qvel: jax.Array, ctrl: jax.Array) -> Any:
        return mg.forward(self.mjx_model, self._template_data, fields, qpos, qvel, ctrl)

    def cpu_sensordata(self, sensordata: jax.Array) -> jax.Array:
        """``[M, nsensordata]`` of the CPU model from the MJX model's (split contact sensors summed back)."""
        sd = sensordata[:, : self.model.nsensordata]
        for adr, extra in self._split_adr:
            sd = sd.at[:, adr].add(sum(sensordata[:, e] for e in extra))
        return sd

    # ---- task ---------------------------------------------------------------------------------
    def sensors(self, data: Any, info: dict, steps: jax.Array) -> dict:
        """``walking.read_sensors`` plus the gait clock at episode step ``steps`` and the episode state."""
        s = walking.read_sensors(self.cpu_sensordata(data.sensordata), data.qpos, data.qvel, self.layout)
        row = jnp.minimum(steps, self.config.episode_length)
        s["phase"], s["stance"] = self.phase_table[row], self.stance_table[row]
        s["command"], s["last_act"] = info["command"], info["last_act"]
        return s

    def base_velocity(self, state: WalkingMjxState) -> jax.Array:
        """[M, 3] measured body-frame (vx, vy) and yaw rate, as the CPU task's ``base_velocity`` (walking metric)."""
        sd, index = self.cpu_sensordata(state.data.sensordata), self.layout["index"]
        (lin, _), (gyro, _) = index["local_linvel"], index["gyro"]
        return jnp.concatenate([sd[:, lin : lin + 2], sd[:, gyro + 2 : gyro + 3]], axis=1)

    def _noise(self, key: jax.Array, n: int) -> jax.Array:
        return jax.random.uniform(key, (n, self.noise_scale.shape[0]), jnp.float32, -1.0, 1.0) * self.noise_scale

    def ctrl(self, a: jax.Array) -> jax.Array:
        """Servo targets: the default pose, plus ``action_scale * a`` on the policy's actuators."""
        n = a.shape[0]
        return _tile(self.default_ctrl, n).at[:, self.policy_idx].add(self.config.action_scale * a)

    def _reset_draws(self, key: jax.Array, fields: dict, extra: dict) -> tuple[Any, dict]:
        """New episodes (the CPU task's ``_reset_envs``) of the envs of these rows (``extra``: their
        ``WalkingMjxState.extra``): data after ``mjx.forward``, info with a new command."""
        c = self.config
        n = jax.tree_util.tree_leaves(fields)[0].shape[0]
        ks = jax.random.split(key, 4)
        qpos, qvel = place_base(self.init_qpos, _uniform(ks[0], (n, 2), -c.reset_xy, c.reset_xy),
                                   _uniform(ks[1], (n,), -c.reset_yaw, c.reset_yaw),
                                   _uniform(ks[2], (n, 6), -c.reset_base_vel, c.reset_base_vel), self.model.nv)
        data = self.forward(fields, self.place(qpos, extra), qvel, _tile(self.default_ctrl, n))
        info = {"command": _uniform(ks[3], (n, 3), self._cmd_low, self._cmd_high),
                "last_act": jnp.zeros((n, self.spec.action_dim))}
        return data, info

    def _observe(self, data: Any, info: dict, steps: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        t = self.template
        return self.extend_obs(data, *walking.observe(self.sensors(data, info, steps), info["last_act"],
                                                      self._noise(key, steps.shape[0]), t.default_pose, t.phase_groups,
                                                      t.critic_extra))

    def reset(self, key: jax.Array, dr: dict | None = None) -> WalkingMjxState:
        """Every env at the start of an episode; ``dr`` (numpy or jax, the CPU task's keys) fixes the
        domain-randomisation draw, otherwise it is sampled from ``key``."""
        n = self.num_envs
        k_dr, k_reset, k_obs, k_state = jax.random.split(key, 4)
        dr = self.sample_dr(k_dr, n) if dr is None else {k: jnp.asarray(v, jnp.float32) for k, v in dr.items()}
        fields = self.model_fields(dr)
        extra = self.init_extra(jax.random.fold_in(k_dr, 3), dr, n)
        data, info = self._reset_draws(k_reset, fields, extra)
        steps = jnp.zeros((n,), jnp.int32)
        obs, cobs = self._observe(data, info, steps, k_obs)
        return WalkingMjxState(data=data, model_fields=fields, info=info, steps=steps, obs=obs, critic_obs=cobs,
                               episode_return=jnp.zeros((n,)), episode_length=jnp.zeros((n,), jnp.int32), key=k_state,
                               extra=extra)

    def step(self, state: WalkingMjxState, action: jax.Array) -> tuple[WalkingMjxState, MjxStepOut]:
        """One control step of every env (``action [M, action_dim]``, NaN -> 0, clipped to +-action_clip if
        that is > 0; the motors get it ``extra["delay"]`` steps late with ``dr_action_delay``); ended envs
        auto-reset (``MjxStepOut.obs`` after the reset, ``next_obs`` before it)."""
        a = jnp.nan_to_num(action.astype(jnp.float32), nan=0.0)
        if self.config.action_clip > 0:
            a = jnp.clip(a, -self.config.action_clip, self.config.action_clip)
        applied, state = mg.delayed(state, a)
        return self.after_physics(state, self.physics_step(state.model_fields, state.data, self.ctrl(applied)), a)

    def after_physics(self, state: WalkingMjxState, data: Any, a: jax.Array) -> tuple[WalkingMjxState, MjxStepOut]:
        """``transition``, then fresh episodes for the envs that ended."""
        st, out = self.transition(state, data, a)
        ended = out.terminated | out.truncated
        key, k_reset = jax.random.split(st.key)
        st, out = self.after_transition(state, st, out, ended, jax.random.fold_in(k_reset, 1))
        zeros = jnp.zeros_like(st.steps)

        def reset_rows(k_data, k_obs, rows):
            fields, extra = jax.tree_util.tree_map(lambda x: x[rows], (st.model_fields, st.extra))
            r_data, r_info = self._reset_draws(k_data, fields, extra)
            r_obs, r_cobs = self._observe(r_data, r_info, zeros[rows], k_obs)
            return r_data, r_info, r_obs, r_cobs

        data, info, obs, cobs = mg.reset_in_batches(ended, (st.data, st.info, st.obs, st.critic_obs), k_reset,
                                                    self.reset_batch, reset_rows)
        new_state = mg.restart_episodes(st, ended, key, data=data, info=info, obs=obs, critic_obs=cobs)
        return new_state, out._replace(obs=obs, critic_obs=cobs)

    def transition(self, state: WalkingMjxState, data: Any, a: jax.Array) -> tuple[WalkingMjxState, MjxStepOut]:
        """Observation, reward, end flags, pushes and bookkeeping of a control step from the post-physics
        ``data`` and the applied action ``a``, before any auto-reset (the returned state's and MjxStepOut's
        ``obs`` are ``next_obs``). The parity tests call it on data from ``forward``."""
        c, n, t = self.config, self.num_envs, self.template
        key, k_noise, k_push = jax.random.split(state.key, 3)
        steps = state.steps + 1
        s = self.sensors(data, state.info, steps)
        next_obs, next_cobs, done, scaled, reward = walking.step_math(
            s, a, self._noise(k_noise, n), t.default_pose, t.phase_groups, c, t.scales, self.dt, t.reward_terms,
            t.critic_extra)
        next_obs, next_cobs = self.extend_obs(data, next_obs, next_cobs)
        if self._push_every:  # the CPU task's ``_push``: after the observation, envs not terminated
            due = (steps % self._push_every == 0) & ~done
            lim = jnp.asarray(c.push_vel, jnp.float32)
            dv = jnp.where(due[:, None], _uniform(k_push, (n, 3), -lim, lim), 0.0)
            data = data.replace(qvel=data.qvel.at[:, 0:3].add(dv))
        out = mg.finish_transition(state, data, steps, done, next_obs, next_cobs, reward, scaled, c.episode_length,
                                   self.at_limit(data))
        info = {"command": state.info["command"], "last_act": a}
        new_state = state._replace(data=data, info=info, steps=steps, obs=out.obs, critic_obs=out.critic_obs,
                                   episode_return=out.episode_return, episode_length=out.episode_length, key=key)
        return new_state, out


def make(config: walking.WalkingConfig, num_envs: int, reset_batch: int = 0) -> WalkingMjx:
    """The MJX env of the walking task whose config ``config`` is (``Go2JoystickConfig``, ``G1WalkConfig``)."""
    for config_cls, task_cls in _CONFIG_CLASSES.items():
        if type(config) is config_cls:
            return WalkingMjx(task_cls, config, num_envs, reset_batch)
    raise ValueError(f"no MJX walking task for config {type(config).__name__}")
