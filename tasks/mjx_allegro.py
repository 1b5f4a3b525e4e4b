"""``allegro_rotate`` on MJX: the CPU task's MDP stepped under ``jax.jit`` (as ``tasks/mjx_go1.py`` is Go1's).

Everything that defines the task comes from ``tasks/allegro_rotate.py``: the MjSpec model (``build_spec``:
pyramidal cone, ``implicitfast``, the same gains and limits), ``mjx.put_model(model, impl="jax")``, and the
shim-written math -- ``step_math`` (observation, reward, fall), ``next_targets`` (HORA's relative targets),
``object_fields`` (the per-episode object as model fields), ``shape_one_hot`` and ``yaw_quat`` -- on jax
arrays; the random draws have the CPU task's distributions, from a jax key. The physics, reset batching
and end-of-step handling are ``tasks/mjx_go1.py``'s task-independent pieces.

Restriction: MJX has no box-cylinder collision (the hand's links are boxes), so the MJX variant takes
``shapes=("box",)`` only and says so for any other config; the CPU task with that override is the same
MDP (its parity test runs boxes).
With ``grasp_cache`` the resets draw from the CPU task's grasps (``tasks/allegro_grasps.py``'s ``draw``, the
boxes of the cache). Per-episode objects: the object's model fields (geom size / position / bounds / friction,
body mass / inertia / centre of mass) live per env in the state and are rewritten for the envs that reset.
"""

from __future__ import annotations

import contextlib
import io
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from tasks import allegro_grasps, base
from tasks import allegro_rotate as ar
from tasks.mjx_go1 import MjxStepOut, finish_transition, forward, physics_step, reset_in_batches, restart_episodes
from tasks.model_edits import sensor_index

with contextlib.redirect_stdout(io.StringIO()):  # mujoco.mjx prints a notice when the optional warp is absent
    from mujoco import mjx

GEOM_FIELDS = ("geom_size", "geom_pos", "geom_aabb", "geom_rbound", "geom_friction")
BODY_FIELDS = ("body_mass", "body_inertia", "body_ipos")


class AllegroMjxState(NamedTuple):
    """Batched state of ``num_envs`` environments (every leaf has the env axis first)."""

    data: Any  # mjx.Data
    model_fields: dict  # per-env model fields (``GEOM_FIELDS + BODY_FIELDS``, whole arrays)
    params: jax.Array  # [M, 8] the episodes' object parameters (``AllegroRotate.params``)
    info: dict  # target, obj_pos, obj_quat (``allegro_rotate.step_math``)
    steps: jax.Array  # [M] int32
    obs: jax.Array
    critic_obs: jax.Array
    episode_return: jax.Array
    episode_length: jax.Array
    key: jax.Array


class AllegroRotateMjx:
    """``reset(key) -> AllegroMjxState``; ``step(state, action) -> (AllegroMjxState, MjxStepOut)``; pure and
    jit-able."""

    def __init__(self, config: ar.AllegroRotateConfig, num_envs: int, reset_batch: int = 0):
        c = config
        self.nsub = ar.check_config(c)
        if tuple(c.shapes) != ("box",):
            raise ValueError(f"the MJX variant needs shapes=('box',), got {c.shapes!r}: MJX has no box-cylinder "
                             "collision (the hand's links are boxes)")
        if num_envs <= 0:
            raise ValueError(f"num_envs must be positive, got {num_envs}")
        self.config, self.num_envs, self.dt = c, int(num_envs), c.ctrl_dt
        self.reset_batch = int(reset_batch or min(num_envs, max(32, math.ceil(num_envs / 16))))
        self.model = ar.build_spec(c).compile()
        m = self.model
        self.mjx_model = mjx.put_model(m, impl="jax")
        self._template = mjx.make_data(self.mjx_model)
        self.kinds = tuple(c.shapes)
        self.obj_body = m.body("object").id
        self.obj_geoms = np.array([m.geom(k).id for k in self.kinds])
        f32 = lambda x: jnp.asarray(np.asarray(x, dtype=np.float32))
        self.nominal = f32([ar.NOMINAL_SIZE[k] for k in self.kinds])
        self.half_z = f32([ar.NOMINAL_SIZE[k][1 if k == "cylinder" else 2] for k in self.kinds])
        self.lower, self.upper = (f32(x) for x in m.actuator_ctrlrange.T)
        self.consts = {"canonical": f32(ar.CANONICAL_POSE), "palm": f32([*ar.PALM_CENTER, ar.PALM_TOP])}
        adr = sensor_index(m)[f"{m.actuator(0).name}_torque"][0]
        self._torque = slice(adr, adr + ar.NJ)
        self.noise_scale = f32(np.r_[np.full(ar.NJ, c.noise_joint_pos), np.full(ar.NJ, c.noise_joint_vel)]
                               * c.noise_level)
        self.scales = ar.reward_scales(c)
        # The CPU task's grasp cache (``grasp_cache``), as device arrays.
        self.grasps = (jax.tree_util.tree_map(jnp.asarray, allegro_grasps.load(c)) if c.grasp_cache else None)
        self.spec = base.TaskSpec(
            name=ar.NAME, obs_dim=ar.actor_obs_dim(c), critic_obs_dim=ar.CRITIC_OBS_DIM, action_dim=ar.NJ,
            episode_length=c.episode_length, ctrl_dt=c.ctrl_dt, reward_terms=ar.REWARD_TERMS,
            privileged_dim=ar.extrinsics_dim(c),
        )

    # ---- objects --------------------------------------------------------------------------------
    def sample_objects(self, key: jax.Array, n: int) -> dict[str, jax.Array]:
        """The CPU task's ``sample_objects`` distributions from a jax key."""
        c = self.config
        ks = jax.random.split(key, 5)
        active = jax.nn.one_hot(jax.random.randint(ks[0], (n,), 0, len(self.kinds)), len(self.kinds))
        if not c.domain_randomization:
            return {"active": active, "scale": jnp.ones(n), "mass": jnp.full(n, 0.06), "friction": jnp.ones(n),
                    "com": jnp.zeros((n, 3))}
        u = lambda k, shape, lo, hi: jax.random.uniform(k, shape, jnp.float32, lo, hi)
        return {"active": active, "scale": u(ks[1], (n,), *c.dr_scale), "mass": u(ks[2], (n,), *c.dr_mass),
                "friction": u(ks[3], (n,), *c.dr_friction),
                "com": u(ks[4], (n, 3), -c.dr_com_offset, c.dr_com_offset)}

    def object_model_fields(self, fields: dict, draws: dict) -> tuple[dict, jax.Array]:
        """``fields`` (rows of the env axis) with the object rewritten from ``draws``; and the params [n, 8]."""
        f = ar.object_fields(draws["active"], draws["scale"], draws["mass"], draws["com"], draws["friction"],
                             self.nominal, self.kinds)
        out = dict(fields)
        for name in GEOM_FIELDS:
            out[name] = fields[name].at[:, self.obj_geoms].set(f[name])
        for name in BODY_FIELDS:
            out[name] = fields[name].at[:, self.obj_body].set(f[name])
        params = jnp.concatenate([draws["mass"][:, None], draws["com"], draws["friction"][:, None],
                                  draws["scale"][:, None], ar.shape_one_hot(draws["active"], self.kinds)], axis=1)
        return out, params

    def base_fields(self, n: int) -> dict:
        m = self.mjx_model
        return {k: jnp.broadcast_to(getattr(m, k), (n, *getattr(m, k).shape)) for k in GEOM_FIELDS + BODY_FIELDS}

    # ---- task ---------------------------------------------------------------------------------
    def _noise(self, key: jax.Array, n: int) -> jax.Array:
        return jax.random.uniform(key, (n, self.noise_scale.shape[0]), jnp.float32, -1.0, 1.0) * self.noise_scale

    def _state(self, data: Any):
        q = data.qpos
        return (q[:, :ar.NJ], data.qvel[:, :ar.NJ], q[:, ar.NJ:ar.NJ + 3], q[:, ar.NJ + 3:ar.NJ + 7],
                data.sensordata[:, self._torque])

    def _reset_rows(self, key: jax.Array, fields: dict) -> tuple[Any, dict, jax.Array, dict]:
        """Fresh episodes for ``fields``' rows: (data after ``mjx.forward``, new fields, params, info)."""
        c, n = self.config, fields["body_mass"].shape[0]
        ks = jax.random.split(key, 3)
        if self.grasps is not None:  # the CPU task's draw: a shape, then one of its grasps
            shape = jax.random.randint(ks[0], (n,), 0, len(self.kinds))
            draws = allegro_grasps.draw(self.grasps, shape, jax.random.uniform(ks[1], (n,), jnp.float32))
            qpos, target = draws["qpos"], draws["target"]
        else:
            draws = self.sample_objects(ks[0], n)
            noise = jax.random.uniform(ks[1], (n, ar.NJ), jnp.float32, -c.reset_pose_noise, c.reset_pose_noise)
            pose = jnp.clip(self.consts["canonical"] + noise, self.lower, self.upper)
            height = ar.PALM_TOP + 0.001 + draws["scale"] * (draws["active"] @ self.half_z)
            pos = jnp.stack([jnp.full(n, ar.PALM_CENTER[0]), jnp.full(n, ar.PALM_CENTER[1]), height], axis=1)
            quat = ar.yaw_quat(jax.random.uniform(ks[2], (n,), jnp.float32, -math.pi, math.pi))
            qpos = jnp.concatenate([pose, pos, quat], axis=1)
            press = jnp.asarray(ar.press_offset(c.reset_press), jnp.float32)
            target = jnp.clip(pose + press, self.lower, self.upper)
        fields, params = self.object_model_fields(fields, draws)
        data = forward(self.mjx_model, self._template, fields, qpos, jnp.zeros((n, self.model.nv)), target)
        info = {"target": target, "obj_pos": qpos[:, ar.NJ:ar.NJ + 3], "obj_quat": qpos[:, ar.NJ + 3:]}
        return data, fields, params, info

    def _observe(self, data: Any, info: dict, params: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        jp, jv, pos, quat, tau = self._state(data)
        zero = jnp.zeros_like(pos)
        return ar.observe(jp, jv, pos, quat, tau, info["target"], zero, zero, params,
                          self._noise(key, jp.shape[0]), self.consts, self.config)

    def reset(self, key: jax.Array) -> AllegroMjxState:
        n = self.num_envs
        k_reset, k_obs, k_state = jax.random.split(key, 3)
        data, fields, params, info = self._reset_rows(k_reset, self.base_fields(n))
        obs, cobs = self._observe(data, info, params, k_obs)
        return AllegroMjxState(data=data, model_fields=fields, params=params, info=info,
                               steps=jnp.zeros((n,), jnp.int32), obs=obs, critic_obs=cobs,
                               episode_return=jnp.zeros((n,)), episode_length=jnp.zeros((n,), jnp.int32), key=k_state)

    def step(self, state: AllegroMjxState, action: jax.Array) -> tuple[AllegroMjxState, MjxStepOut]:
        """One control step of every env (``action`` clipped to [-1, 1], NaN -> 0); ended envs auto-reset."""
        a = jnp.clip(jnp.nan_to_num(action.astype(jnp.float32), nan=0.0), -1.0, 1.0)
        target = ar.next_targets(state.info["target"], a, self.config.action_scale, self.lower, self.upper)
        state = state._replace(info={**state.info, "target": target})
        data = physics_step(self.mjx_model, self.nsub, state.model_fields, state.data, target)
        st, out = self.transition(state, data)
        ended = out.terminated | out.truncated
        key, k_reset = jax.random.split(st.key)

        def reset_rows(k_r, k_o, rows):
            fields = jax.tree_util.tree_map(lambda x: x[rows], st.model_fields)
            r_data, r_fields, r_params, r_info = self._reset_rows(k_r, fields)
            r_obs, r_cobs = self._observe(r_data, r_info, r_params, k_o)
            return r_data, r_fields, r_params, r_info, r_obs, r_cobs

        carry = (st.data, st.model_fields, st.params, st.info, st.obs, st.critic_obs)
        data, fields, params, info, obs, cobs = reset_in_batches(ended, carry, k_reset, self.reset_batch, reset_rows)
        new_state = restart_episodes(st, ended, key, data=data, model_fields=fields, params=params, info=info,
                                     obs=obs, critic_obs=cobs)
        return new_state, out._replace(obs=obs, critic_obs=cobs)

    def transition(self, state: AllegroMjxState, data: Any) -> tuple[AllegroMjxState, MjxStepOut]:
        """Observation, reward, end flags and bookkeeping from the post-physics ``data`` (``state.info["target"]``
        already the applied targets), before any auto-reset. The parity test calls it on data from ``forward``."""
        c, n = self.config, self.num_envs
        key, k_noise = jax.random.split(state.key)
        jp, jv, pos, quat, tau = self._state(data)
        next_obs, next_cobs, done, scaled, reward, _ = ar.step_math(
            jp, jv, pos, quat, tau, state.info, state.params, self._noise(k_noise, n), self.consts, c, self.scales,
            self.dt)
        steps = state.steps + 1
        out = finish_transition(state, data, steps, done, next_obs, next_cobs, reward, scaled, c.episode_length)
        info = {**state.info, "obj_pos": pos, "obj_quat": quat}
        new_state = state._replace(data=data, info=info, steps=steps, obs=out.obs, critic_obs=out.critic_obs,
                                   episode_return=out.episode_return, episode_length=out.episode_length, key=key)
        return new_state, out


def make(config: ar.AllegroRotateConfig, num_envs: int, reset_batch: int = 0) -> AllegroRotateMjx:
    return AllegroRotateMjx(config, num_envs, reset_batch)
