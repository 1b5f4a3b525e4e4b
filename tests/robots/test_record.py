"""Demonstrations: recording through robot servers into a replay store, teleoperation devices, prior-data loading."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from unilab_jax.apps import record
from unilab_jax.fields import REPLAY_FIELDS
from unilab_jax.robots import teleop
from unilab_jax.runtime.prior import PriorDataError, load_prior
from unilab_jax.runtime.replay_store import ReplayStore


def test_record_peg_demos_through_servers(tmp_path, capsys):
    out = str(tmp_path / "demos")
    rc = record.main(["--robots=sim:franka_emika_panda,sim:franka_emika_panda", "--task=robot_peg_insertion",
                      "--episodes=3", f"--out={out}", "--speed=50"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["episodes"] == 3 and summary["successes"] == 3  # the scripted expert: 100% (docs/MANIPULATION.md)
    with ReplayStore(out) as store:
        rows = store.read(store.first_row, store.committed)
        assert store.info["task"] == "robot_peg_insertion" and store.info["device"] == "expert"
    assert sorted(set(rows["episode"].tolist())) == [0, 1, 2]
    assert len(rows["reward"]) == summary["transitions"]
    assert rows["success"].all()
    for e in range(3):
        ep = rows["episode"] == e
        assert np.all(np.diff(np.flatnonzero(ep)) == 1)  # whole episodes, contiguous
        obs, nxt = rows["obs"][ep], rows["next_obs"][ep]
        np.testing.assert_array_equal(obs[1:], nxt[:-1])  # a chain of steps of one robot
        assert rows["terminated"][ep][-1] and not rows["terminated"][ep][:-1].any()
        assert np.abs(rows["action"][ep]).max() <= 1.0
    # 13 proprio + 2 kinds, no inventory place: the layout the robot experiments have (robot_cli.ROBOT_TASK)
    assert rows["obs"].shape[1] == 15
    loaded = load_prior(out, {k: ((int(rows[k].shape[1]),) if rows[k].ndim > 1 else (), rows[k].dtype)
                              for k in REPLAY_FIELDS})
    assert set(loaded) == set(REPLAY_FIELDS)
    np.testing.assert_array_equal(loaded["obs"], rows["obs"])
    with pytest.raises(PriorDataError, match="field 'obs' is"):
        load_prior(out, {"obs": ((16,), np.dtype(np.float32))})


def test_record_refuses_bad_flags(tmp_path, capsys):
    full = tmp_path / "full"
    full.mkdir()
    (full / "x").write_text("x")
    cases = [([f"--out={full}"], "is not empty"), ([f"--out={tmp_path / 'a'}", "--task=cartpole"], "choose one of"),
             ([f"--out={tmp_path / 'a'}", "--device=spacemouse"], "no SpaceMouse driver"),
             ([f"--out={tmp_path / 'a'}", "--episodes=0"], "must be positive"),
             ([f"--out={tmp_path / 'a'}", "--robots=sim:nope"], "")]
    try:
        os.close(os.open("/dev/tty", os.O_RDONLY))
    except OSError:  # no terminal (CI): the keyboard is refused before any robot starts
        cases.append(([f"--out={tmp_path / 'a'}", "--device=keyboard"], "reads keys from the terminal"))
    for argv, message in cases:
        assert record.main(argv) == 2
        assert message in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "a")
    with pytest.raises(PriorDataError, match="no replay store"):
        load_prior(str(tmp_path / "a"), {})


def test_keyboard_device_maps_keys_to_actions():
    r, w = os.pipe()
    device = teleop.KeyboardDevice(fd=r)
    try:
        assert isinstance(device, teleop.TeleopDevice)
        np.testing.assert_array_equal(device({}), [0, 0, 0, 0, 0, 0, -1])  # nothing pressed: hold, gripper open
        os.write(w, b"wwa f")  # +x twice (clipped to 1), +y, gripper toggles closed, -z
        np.testing.assert_array_equal(device({}), [1, 1, -1, 0, 0, 0, 1])
        os.write(w, b"qx")  # +yaw; unknown keys ignored; the gripper stays closed
        np.testing.assert_array_equal(device({}), [0, 0, 0, 0, 0, 1, 1])
        device.reset()
        np.testing.assert_array_equal(device({})[6], -1)
    finally:
        device.close()
        os.close(r)
        os.close(w)


def test_expert_device_is_the_scripted_expert():
    from unilab_jax.robots.experts import make_expert
    from unilab_jax.robots.sim import SimConfig, SimRobot

    robot = SimRobot(SimConfig(arm="franka", task="peg_insertion", cameras=(), speed=float("inf"),
                               reset_seconds=0.0, seed=3))
    try:
        obs = robot.reset(seed=3)
        device, expert = teleop.make_device("expert", robot.spec), make_expert(robot.spec)
        assert isinstance(device, teleop.TeleopDevice)
        device.reset()
        np.testing.assert_array_equal(device(obs), expert(obs))
    finally:
        robot.close()
    with pytest.raises(ValueError, match="unknown teleoperation device"):
        teleop.make_device("joystick", robot.spec)


def test_policy_state_puts_the_object_state_in_the_observation():
    import tasks

    plain = tasks.make("robot_peg_insertion", num_envs=2, seed=1)
    task = tasks.make("robot_peg_insertion", num_envs=2, seed=1, overrides={"policy_state": True})
    try:
        p, o = task.robot_spec.privileged_dim, plain.spec.obs_dim
        assert task.spec.obs_dim == o + p and task.spec.critic_obs_dim == plain.spec.critic_obs_dim + p
        obs, critic = task.reset()
        proprio = task.robot_spec.proprio_dim
        # proprio, then the privileged state (as the critic sees it after the observation), then kind and identity
        np.testing.assert_array_equal(obs[:, proprio:proprio + p], critic[:, o + p:o + 2 * p])
    finally:
        plain.close()
        task.close()


def test_recorded_demos_are_what_the_learner_sees_online(tmp_path):
    """Demonstrations recorded on in-process robots with the policy state, the dense reward and the rotation
    locked: each stored action is the expert's action on the stored observation as executed (unscaled, its
    rotation zeroed by ``lock_rotation``), the observation is the
    task's online one (its policy-state block equals the privileged block of the critic observation), and each
    reward is the potential-based shaping computed by hand from the stored critic observations: the rewards of
    an episode sum to the success bonus plus the potential's change (Ng et al.'s telescoping sum)."""
    import tasks
    from unilab_jax.robots.experts import make_expert
    from unilab_jax.robots.manipulation import SUCCESS_BONUS, PegGeometry, peg_potential

    task = tasks.make("robot_peg_insertion", num_envs=2, seed=4, overrides={"policy_state": True, "dense_reward": True,
                                                                             "lock_rotation": True})
    out = str(tmp_path / "demos")
    try:
        with ReplayStore(out, record.demo_layout(task.spec)) as store:
            summary = record._run(task, [teleop.make_device("expert", task.robot_spec) for _ in range(2)], store, 3)
            store.flush()
            rows = store.read(store.first_row, store.committed)
        spec, o, p = task.robot_spec, task.spec.obs_dim, task.robot_spec.privileged_dim
    finally:
        task.close()
    assert summary["episodes"] == 3 and summary["successes"] == 3
    privileged = rows["critic_obs"][:, o:o + p]
    np.testing.assert_array_equal(rows["obs"][:, spec.proprio_dim:spec.proprio_dim + p], privileged)
    g = PegGeometry()

    def potential(critic_obs):
        state = critic_obs[o + 8:o + p].astype(np.float64)
        return peg_potential(state[:3], state[3:6], g)

    rotated = 0.0  # the largest rotation command of the expert: the lock had something to zero
    for e in range(3):
        ep = np.flatnonzero(rows["episode"] == e)
        expert = make_expert(spec)
        for i in ep:
            commanded = expert({"privileged": privileged[i]})
            rotated = max(rotated, float(np.abs(commanded[3:6]).max()))
            np.testing.assert_array_equal(rows["action"][i], np.r_[commanded[:3], 0.0, 0.0, 0.0, commanded[6]])
            want = (SUCCESS_BONUS * rows["terminated"][i] + potential(rows["next_critic_obs"][i])
                    - potential(rows["critic_obs"][i]))
            assert rows["reward"][i] == pytest.approx(want, abs=1e-4)
        total = rows["reward"][ep].sum()
        change = potential(rows["next_critic_obs"][ep[-1]]) - potential(rows["critic_obs"][ep[0]])
        assert total == pytest.approx(SUCCESS_BONUS + change, abs=1e-3)
    assert rotated > 1e-4
