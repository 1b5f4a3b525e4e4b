"""Go2 joystick and G1 walk: reward terms and gait phase by hand, then the tasks on a real simulation."""

from __future__ import annotations

import math

import numpy as np
import pytest

import tasks
from tasks import g1_walk, go2_joystick, walking
from tasks.physics import BatchedSim

GO2_DEFAULT = np.array([0.0, 0.9, -1.8] * 4)
CLEAN = {"noise_level": 0.0, "domain_randomization": False, "reset_base_vel": 0.0, "reset_xy": 0.0,
         "reset_yaw": 0.0}


def row(*xs):
    return np.array([xs], dtype=np.float64)


def go2_terms(**kw):
    """Go2 reward terms on one env with neutral defaults, overridden by ``kw``."""
    args = dict(
        command=row(0.0, 0.0, 0.0), local_linvel=row(0.0, 0.0, 0.0), gyro=row(0.0, 0.0, 0.0), base_z=np.array([0.3]),
        joint_pos=GO2_DEFAULT[None].copy(), default_pose=GO2_DEFAULT, action=np.zeros((1, 12)),
        last_act=np.zeros((1, 12)), contact=np.zeros((1, 4), bool), stance=np.zeros((1, 4), bool),
        feet_h=np.zeros((1, 4)), tracking_sigma=0.4, base_height_target=0.3, swing_height_target=0.1,
        swing_height_sigma=0.01,
    )
    args.update(kw)
    return {k: float(v[0]) for k, v in go2_joystick.reward_terms(**args).items()}


# --------------------------------------------------------------------------------------------------
# Hand-computed Go2 terms
# --------------------------------------------------------------------------------------------------
def test_go2_tracking_kernels():
    t = go2_terms(command=row(1.0, 0.5, 0.4), local_linvel=row(0.8, 0.1, 7.0), gyro=row(3.0, 3.0, 0.0))
    # lin: (1.0 - 0.8)^2 + (0.5 - 0.1)^2 = 0.2 -> exp(-0.2 / 0.4); ang: 0.4^2 = 0.16 -> exp(-0.16 / 0.4)
    assert t["tracking_lin_vel"] == pytest.approx(math.exp(-0.5))
    assert t["tracking_ang_vel"] == pytest.approx(math.exp(-0.4))
    assert t["lin_vel_z"] == pytest.approx(49.0)  # body-frame vz^2
    assert t["ang_vel_xy"] == pytest.approx(18.0)  # roll rate^2 + pitch rate^2


def test_go2_base_height_pose_and_action_rate():
    q = GO2_DEFAULT.copy()
    q[0], q[4], q[11] = 0.1, 0.9 - 0.2, -1.8 + 0.05
    a = np.full((1, 12), 0.5)
    a[0, 3] = -1.5  # unclipped actions enter the action rate as they are
    t = go2_terms(base_z=np.array([0.25]), joint_pos=q[None], action=a, last_act=np.full((1, 12), 0.4))
    assert t["base_height"] == pytest.approx(0.05**2)
    assert t["pose"] == pytest.approx(0.1 + 0.2 + 0.05)  # L1, not squared
    assert t["action_rate"] == pytest.approx(11 * 0.01 + 1.9**2)


def test_go2_phase_matched_contact_and_swing_height():
    contact = np.array([[True, False, True, False]])
    stance = np.array([[True, True, False, False]])
    feet_h = np.array([[0.3, 0.05, 0.0, 0.1]])
    t = go2_terms(contact=contact, stance=stance, feet_h=feet_h)
    # matches: foot 0 (stance, touching) and foot 3 (swing, lifted); foot 1 lifted in stance, foot 2 touching in swing
    assert t["feet_contact_phase"] == 2.0
    # swing feet 2 and 3 only: exp(-(0 - 0.1)^2 / 0.01) + exp(-(0.1 - 0.1)^2 / 0.01); foot 0 is 0.3 high but in stance
    assert t["feet_swing_height"] == pytest.approx(math.exp(-1.0) + 1.0)
    everywhere = go2_terms(contact=~stance, stance=stance)
    assert everywhere["feet_contact_phase"] == 0.0


def test_gait_phase_trot_and_features():
    offsets = np.array([0.0, 0.5, 0.5, 0.0])
    t = np.array([0.0, 0.1, 0.3, 0.5])
    ph = walking.gait_phase(t, 2.0, offsets)
    np.testing.assert_allclose(ph, [[0.0, 0.5, 0.5, 0.0], [0.2, 0.7, 0.7, 0.2], [0.6, 0.1, 0.1, 0.6],
                                    [0.0, 0.5, 0.5, 0.0]], atol=1e-12)
    # diagonal pairs alternate: FL/RR in stance while FR/RL swing, and the other way round half a period later
    np.testing.assert_array_equal(walking.stance_mask(ph, 0.5)[1:3], [[True, False, False, True],
                                                                      [False, True, True, False]])
    f = walking.phase_features(ph[:, [0, 1]])
    a, b = 2 * math.pi * 0.2, 2 * math.pi * 0.7
    np.testing.assert_allclose(f[1], [math.sin(a), math.cos(a), math.sin(b), math.cos(b)], atol=1e-12)


def test_tilt_and_height_termination():
    def grav(deg):  # projected gravity of a body pitched by deg
        r = math.radians(deg)
        return [math.sin(r), 0.0, -math.cos(r)]

    g = np.array([grav(0), grav(59), grav(61), grav(180)])
    np.testing.assert_array_equal(walking.terminated(g, np.full(4, 1.0), 60.0, 0.0), [False, False, True, True])
    np.testing.assert_array_equal(walking.terminated(g[:1].repeat(2, 0), np.array([0.29, 0.31]), 60.0, 0.3),
                                  [True, False])


def test_walking_math_runs_on_jax():
    jnp = pytest.importorskip("jax.numpy")
    rng = np.random.default_rng(0)
    args = dict(
        command=rng.normal(size=(3, 3)), local_linvel=rng.normal(size=(3, 3)), gyro=rng.normal(size=(3, 3)),
        base_z=rng.random(3), joint_pos=rng.normal(size=(3, 12)), default_pose=GO2_DEFAULT,
        action=rng.normal(size=(3, 12)), last_act=rng.normal(size=(3, 12)), contact=rng.random((3, 4)) < 0.5,
        stance=rng.random((3, 4)) < 0.5, feet_h=rng.random((3, 4)) * 0.2,
    )
    kw = dict(tracking_sigma=0.4, base_height_target=0.3, swing_height_target=0.1, swing_height_sigma=0.01)
    ref = go2_joystick.reward_terms(**args, **kw)
    jargs = {k: jnp.asarray(v.astype(np.float32) if v.dtype == np.float64 else v) for k, v in args.items()}
    out = go2_joystick.reward_terms(**jargs, **kw)
    assert tuple(out) == go2_joystick.REWARD_TERMS
    for k in ref:
        np.testing.assert_allclose(np.asarray(out[k]), ref[k], rtol=2e-5, atol=2e-5, err_msg=k)
    g1_args = dict(
        command=args["command"], local_linvel=args["local_linvel"], gyro=args["gyro"],
        gravity=rng.normal(size=(3, 3)), base_z=args["base_z"], joint_pos=rng.normal(size=(3, 15)),
        default_pose=rng.normal(size=15), pose_weight=rng.random(15), action=rng.normal(size=(3, 15)),
        last_act=rng.normal(size=(3, 15)), actuator_force=rng.normal(size=(3, 29)),
        contact=args["contact"][:, :2], stance=args["stance"][:, :2], feet_h=args["feet_h"][:, :2],
        feet_vel=rng.normal(size=(3, 2, 3)), done=rng.random(3) < 0.5,
    )
    kw = dict(tracking_sigma=0.25, base_height_target=0.74, swing_height_target=0.08, swing_height_sigma=0.0025)
    ref = g1_walk.reward_terms(**g1_args, **kw)
    jargs = {k: jnp.asarray(v.astype(np.float32) if v.dtype == np.float64 else v) for k, v in g1_args.items()}
    out = g1_walk.reward_terms(**jargs, **kw)
    assert tuple(out) == g1_walk.REWARD_TERMS
    for k in ref:
        np.testing.assert_allclose(np.asarray(out[k]), ref[k], rtol=1e-4, atol=1e-4, err_msg=k)
    ph = walking.gait_phase(jnp.asarray([0.1, 0.3]), 2.0, jnp.asarray([0.0, 0.5]))
    np.testing.assert_allclose(np.asarray(walking.phase_features(ph)),
                               walking.phase_features(walking.gait_phase(np.array([0.1, 0.3]), 2.0, np.array([0, .5]))),
                               atol=1e-6)


# --------------------------------------------------------------------------------------------------
# Go2 on the real simulation
# --------------------------------------------------------------------------------------------------
def _collides(model):
    """Sorted (body, geom name) of every geom that can collide (unnamed geoms repeat)."""
    return sorted((model.body(model.geom_bodyid[g]).name, model.geom(g).name) for g in range(model.ngeom)
                  if model.geom_contype[g] or model.geom_conaffinity[g])


def test_go2_model_servos_contacts_and_spec():
    task = tasks.make("go2_joystick_flat", 2, seed=0)
    m, s = task.model, task.spec
    assert (s.obs_dim, s.critic_obs_dim, s.action_dim, s.episode_length, s.ctrl_dt) == (49, 52, 12, 1000, 0.02)
    assert m.opt.timestep == 0.01 and task.sim.nsub == 2
    limits = {m.actuator(i).name: m.actuator_forcerange[i, 1] for i in range(m.nu)}
    for leg in go2_joystick.FEET:
        assert (limits[f"{leg}_hip"], limits[f"{leg}_thigh"], limits[f"{leg}_calf"]) == (23.7, 23.7, 45.43)
    assert (m.actuator_ctrllimited == 0).all() and (m.actuator_forcelimited == 1).all()
    np.testing.assert_allclose(m.actuator_gainprm[:, 0], 35.0)
    np.testing.assert_allclose(m.actuator_biasprm[:, :3], [[0.0, -35.0, 0.0]] * 12)
    np.testing.assert_allclose(m.dof_damping[6:], 0.5)  # kd
    assert _collides(m) == sorted([("world", "floor")] + [(f"{f}_calf", f) for f in go2_joystick.FEET])
    np.testing.assert_allclose(task.default_pose, GO2_DEFAULT)
    task.close()


def test_go2_obs_layout_no_action_clipping_and_reward_sum():
    task = tasks.make("go2_joystick_flat", 2, seed=0, overrides=CLEAN)
    obs, cobs = task.reset()
    np.testing.assert_allclose(obs[:, 3:6], [[0, 0, -1]] * 2, atol=1e-6)  # upright
    np.testing.assert_allclose(obs[:, 6:18], 0.0, atol=1e-6)  # home pose == default pose
    np.testing.assert_allclose(obs[:, 30:42], 0.0)  # no previous action
    np.testing.assert_allclose(obs[:, 42:45], task.command, rtol=1e-6)
    np.testing.assert_allclose(obs[:, 45:49], [[0, 1, 0, -1]] * 2, atol=1e-6)  # phases 0 (FL/RR) and 0.5 (FR/RL)
    np.testing.assert_allclose(cobs[:, :49], obs)
    lo, hi = np.array(go2_joystick.default_config().command_low), np.array(go2_joystick.default_config().command_high)
    assert ((task.command >= lo) & (task.command <= hi)).all()
    cmd = task.command.copy()
    a1 = np.full((2, 12), 0.1, np.float32)
    a2 = np.full((2, 12), -0.2, np.float32)
    a2[:, 1] = 2.5  # beyond [-1, 1]: not clipped
    np.testing.assert_allclose(task._ctrl(a2.astype(np.float64))[0, 1], 0.9 + 0.4 * 2.5)
    task.step(a1)
    o = task.step(a2)
    assert not (o.terminated | o.truncated).any()
    np.testing.assert_allclose(o.next_obs[:, 30:42], a2)  # the action just applied, unclipped
    np.testing.assert_allclose(task.command, cmd)  # one command per episode
    np.testing.assert_allclose(o.next_obs[:, 6:18], task.sim.qpos[:, 7:] - GO2_DEFAULT, atol=1e-6)
    np.testing.assert_allclose(o.next_obs[:, 18:30], task.sim.qvel[:, 6:], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(o.next_obs[:, 0:3], task._s("gyro"), rtol=1e-5, atol=1e-6)
    ph = 2.0 * 0.04 * 2 * math.pi  # phase of FL/RR after 2 steps (t = 0.04 s, 2 Hz)
    np.testing.assert_allclose(o.next_obs[:, 45:47], [[math.sin(ph), math.cos(ph)]] * 2, atol=1e-6)
    np.testing.assert_allclose(o.next_critic_obs[:, 49:52], task._s("local_linvel"), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(task.base_velocity()[:, :2], task._s("local_linvel")[:, :2])
    # each term is 0.02 * scale * term; action rate: 0.02 * -0.02 * (11 * 0.3^2 + 2.4^2)
    np.testing.assert_allclose(o.reward_terms["action_rate"], 0.02 * -0.02 * (11 * 0.09 + 2.4**2), rtol=1e-5)
    np.testing.assert_allclose(o.reward_terms["base_height"],
                               0.02 * -20.0 * (task.sim.qpos[:, 2] - 0.3) ** 2, rtol=1e-5)
    total = np.sum(np.stack(list(o.reward_terms.values())), axis=0)
    np.testing.assert_allclose(o.reward, total, rtol=1e-5, atol=1e-7)  # summed, not clipped at 0
    # a violent action makes the sum negative: Go2's reward is not clipped (Go1's is)
    o = task.step(np.full((2, 12), -10.0, np.float32))
    assert not o.truncated.any() and (o.reward < 0).all()
    task.close()


def test_go2_tilt_terminates_and_timeout_truncates():
    task = tasks.make("go2_joystick_flat", 3, seed=0, overrides=CLEAN)
    task.reset()
    qpos, qvel = task.sim.qpos.copy(), np.zeros_like(task.sim.qvel)
    for i, deg in enumerate((75.0, 40.0)):  # roll about x
        r = math.radians(deg) / 2
        qpos[i, 3:7] = [math.cos(r), math.sin(r), 0.0, 0.0]
    qpos[:, 2] = 0.4
    task.sim.set_state(np.arange(3), qpos, qvel)
    o = task.step(np.zeros((3, 12), np.float32))
    assert o.terminated.tolist() == [True, False, False] and not o.truncated.any()
    task.close()


def test_go2_domain_randomization_and_pushes():
    task = tasks.make("go2_joystick_flat", 4, seed=2, overrides={"push_interval_s": 0.04})
    dr, ext = task.dr, task.extrinsics
    assert [k for k, _ in task.extrinsics_layout] == ["base_com_x", "base_mass_delta", "kd_scale", "kp_scale"]
    assert ext.shape == (4, 26)
    assert (np.abs(dr["base_mass_delta"]) <= 1.5).all() and (np.abs(dr["base_com_x"]) <= 0.05).all()
    assert ((dr["kp_scale"] >= 0.9) & (dr["kp_scale"] <= 1.1)).all() and np.ptp(dr["kp_scale"]) > 0
    base_id = task.model.body("base").id
    for i, mi in enumerate(task.sim.models):
        np.testing.assert_allclose(mi.actuator_gainprm[:, 0], 35.0 * dr["kp_scale"][i])
        np.testing.assert_allclose(-mi.actuator_biasprm[:, 1], 35.0 * dr["kp_scale"][i])
        np.testing.assert_allclose(mi.dof_damping[6:], 0.5 * dr["kd_scale"][i])
        assert mi.body_mass[base_id] == pytest.approx(task.model.body_mass[base_id] + dr["base_mass_delta"][i, 0])
        assert mi.body_ipos[base_id, 0] == pytest.approx(task.model.body_ipos[base_id, 0] + dr["base_com_x"][i, 0])
    task.reset()
    zero = np.zeros((4, 12), np.float32)
    task.step(zero)
    assert task.push_count == 0
    before = task.sim.qvel[:, :3].copy()
    task.step(zero)  # 2 steps = 0.04 s: every env is pushed after this step
    assert task.push_count == 4
    assert np.abs(task.sim.qvel[:, :3] - before).max() > 0.05
    task.close()


@pytest.mark.parametrize("engine", ["rollout", "step"])
def test_batched_sim_add_velocity(engine):
    task = tasks.make("go2_joystick_flat", 3, seed=0, overrides={**CLEAN, "physics_engine": engine})
    task.reset()
    sim: BatchedSim = task.sim
    q0, v0 = sim.qpos.copy(), sim.qvel.copy()
    dq = np.zeros((1, sim.nv))
    dq[0, 0] = 1.0
    sim.add_velocity(np.array([1]), dq)
    expected = v0.copy()
    expected[1, 0] += 1.0
    np.testing.assert_allclose(sim.qvel, expected)
    np.testing.assert_array_equal(sim.qpos, q0)
    sim.step(np.tile(task.default_ctrl, (3, 1)))
    # the pushed env moved forward by about the added speed * 0.02 s; the others did not
    assert sim.qpos[1, 0] - q0[1, 0] > 0.01 and abs(sim.qpos[0, 0] - q0[0, 0]) < 0.005
    task.close()


# --------------------------------------------------------------------------------------------------
# G1
# --------------------------------------------------------------------------------------------------
def test_g1_shapes_joints_and_feet_only_contacts():
    task = tasks.make("g1_walk_flat", 2, seed=0)
    m, s = task.model, task.spec
    assert m.nu == 29 and m.opt.timestep == 0.005 and task.sim.nsub == 4
    assert (s.action_dim, s.obs_dim, s.critic_obs_dim, s.privileged_dim) == (15, 58, 66, 34)
    assert all(any(k in n for k in ("hip", "knee", "ankle", "waist")) for n in task.policy_joint_names)
    spheres = [(b, "") for b in ("left_ankle_roll_link", "right_ankle_roll_link") for _ in range(4)]
    assert _collides(m) == sorted([("world", "floor")] + spheres)
    # the servos: torque limits from the motors, per-group gains
    knee = m.actuator("left_knee").id
    wrist = m.actuator("right_wrist_yaw").id
    assert m.actuator_forcerange[knee, 1] == 139.0 and m.actuator_gainprm[knee, 0] == 150.0
    assert m.actuator_forcerange[wrist, 1] == 5.0 and m.actuator_gainprm[wrist, 0] == 20.0
    obs, cobs = task.reset()
    assert obs.shape == (2, 58) and cobs.shape == (2, 66)
    np.testing.assert_allclose(obs[:, 51:54], task.command, rtol=1e-6)
    np.testing.assert_allclose(obs[:, 54:58], [[0, 1, 0, -1]] * 2, atol=1e-6)  # left phase 0, right 0.5
    task.close()
    # reset with the soles touching the floor; a few steps later both feet are on it, soles at ~0 height
    task = tasks.make("g1_walk_flat", 1, seed=0, overrides=CLEAN)
    task.reset()
    assert abs(task.init_qpos[2] - 0.757) < 0.02
    np.testing.assert_allclose(task._sensors()["feet_h"], 0.0, atol=1e-3)  # foot-centre site, sole slightly pitched
    for _ in range(5):
        task.step(np.zeros((1, 15), np.float32))
    s5 = task._sensors()
    assert s5["contact"].all() and s5["feet_vel"].shape == (1, 2, 3)
    np.testing.assert_allclose(s5["feet_h"], 0.0, atol=5e-3)
    task.close()
    full = tasks.make("g1_walk_flat", 1, seed=0, overrides={"policy_joints": "all"})
    assert full.spec.action_dim == 29 and full.spec.obs_dim == 6 + 3 * 29 + 3 + 4
    full.close()


def test_g1_termination_low_pelvis_and_tilt():
    task = tasks.make("g1_walk_flat", 3, seed=0, overrides=CLEAN)
    task.reset()
    qpos, qvel = task.sim.qpos.copy(), np.zeros_like(task.sim.qvel)
    qpos[0, 2] = 0.2  # pelvis below 0.3 m, upright (the floor pushes the sunk feet up ~5 cm in the step)
    r = math.radians(70.0) / 2
    qpos[1, 3:7] = [math.cos(r), 0.0, math.sin(r), 0.0]  # pitched 70 degrees
    task.sim.set_state(np.arange(3), qpos, qvel)
    o = task.step(np.zeros((3, 15), np.float32))
    assert o.terminated.tolist() == [True, True, False]
    np.testing.assert_allclose(o.reward_terms["termination"], [-20 * 0.02, -20 * 0.02, 0.0], rtol=1e-6)
    task.close()


def test_g1_domain_randomization_models():
    task = tasks.make("g1_walk_flat", 3, seed=1)
    dr = task.dr
    floor, torso = task.model.geom("floor").id, task.model.body("torso_link").id
    for i, mi in enumerate(task.sim.models):
        assert mi.geom_friction[floor, 0] == pytest.approx(dr["floor_friction"][i, 0])
        np.testing.assert_allclose(mi.body_mass[1:], task.model.body_mass[1:] * dr["mass_scale"][i])
        np.testing.assert_allclose(mi.body_ipos[torso], task.model.body_ipos[torso] + dr["com_offset"][i])
    assert ((dr["floor_friction"] >= 0.4) & (dr["floor_friction"] <= 1.0)).all()
    assert g1_walk.joint_group("left_wrist_pitch_joint") == "wrist"
    assert g1_walk.joint_group("left_wrist_roll_joint") == "arm" and g1_walk.joint_group("waist_roll_joint") == "waist"
    task.close()
