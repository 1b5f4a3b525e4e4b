"""The operator channel: the scripted expert acting as an operator takes over a robot when the policy is
unsafe, drops the object or stalls, hands back after its segment; each transition's ``source`` and the
executed action travel byte-exact from the task to the learner's replay batch; intervention rates per
episode reach the pool's statistics."""

from __future__ import annotations

import numpy as np
import pytest

import tasks
from tasks.robot import SOURCE_OPERATOR, SOURCE_POLICY
from unilab_jax.fields import REPLAY_FIELDS, replay_fields
from unilab_jax.robots.interface import RobotSpec
from unilab_jax.robots.operator import ExpertOperator, OperatorConfig
from unilab_jax.runtime.pool import WorkerPool

SPEC = RobotSpec(name="r", kind="franka", task="pick_place", proprio_dim=13, privileged_dim=18, cameras=(),
                 image_shape=(64, 64, 3), control_hz=10.0, episode_length=100, max_delta_pos=0.03, max_delta_rot=0.25)


def _obs(tcp, obj=(0.5, 0.05, 0.02), opening=1.0) -> dict[str, np.ndarray]:
    """A pick-and-place observation: tcp pose, gripper opening, cube pose (identity orientation), bin position."""
    p = np.concatenate([tcp, [0.0, 1.0, 0.0, 0.0], [opening], obj, [1.0, 0.0, 0.0, 0.0], [0.48, -0.23, 0.0]])
    return {"privileged": p.astype(np.float32), "proprio": np.zeros(13, np.float32)}


def test_operator_takes_over_when_unsafe_for_one_segment():
    op = ExpertOperator(SPEC, OperatorConfig(mode="gate", segment_steps=3, stall_steps=50))
    policy = np.full(7, 0.5, np.float32)
    inside, outside = _obs([0.45, 0.0, 0.25]), _obs([0.45, 0.0, 0.5])  # z above the box's 0.35
    action, by_op = op.act(inside, policy)
    assert not by_op and action is policy
    op.observe(0.1)
    got = []
    for _ in range(4):  # leaves the box: 3 operator steps, hand-back, and (still outside) a second takeover
        got.append(op.act(outside, policy)[1])
        op.observe(0.1)
    assert got == [True, True, True, True] and op.takeovers == 2 and op.last_reason == "unsafe"
    assert op.steps == 5 and op.operator_steps == 4 and op.rate == pytest.approx(4 / 5)


def test_operator_takes_over_when_progress_stalls_and_hands_back():
    op = ExpertOperator(SPEC, OperatorConfig(mode="gate", segment_steps=2, stall_steps=3))
    inside, policy = _obs([0.45, 0.0, 0.25]), np.zeros(7, np.float32)
    sources = []
    for reward in [0.1, 0.1, 0.0, 0.01, -0.05, 0.0, 0.0, 0.7]:  # potential differences: returns 0.1, 0.2, 0.2, ...
        sources.append(op.act(inside, policy)[1])
        op.observe(reward)
    # steps 1-5: policy (best return 0.2 after step 2; it rises by less than stall_eps = 0.02 (0.21) or falls
    # (0.16) after steps 3, 4, 5 -> a stall of 3 seen at step 6),
    # steps 6-7: the operator's segment, then the policy with a fresh stall allowance.
    assert sources == [False, False, False, False, False, True, True, False]
    assert op.takeovers == 1 and op.last_reason == "stalled" and op.operator_steps == 2


def test_operator_takes_over_when_the_cube_is_dropped():
    op = ExpertOperator(SPEC, OperatorConfig(mode="gate", segment_steps=5, stall_steps=50))
    policy = np.zeros(7, np.float32)
    carried = _obs([0.5, 0.05, 0.15], obj=[0.5, 0.05, 0.14])  # lifted, between the fingers
    assert not op.act(carried, policy)[1]
    op.observe(0.5)
    dropped = _obs([0.5, 0.05, 0.15], obj=[0.5, 0.05, 0.02])  # back on the table
    action, by_op = op.act(dropped, policy)
    assert by_op and op.last_reason == "dropped"
    assert action.shape == (7,) and action[6] == -1.0  # the expert's first phase: gripper open above the cube


def test_operator_taking_over_a_carried_cube_carries_it_on():
    """The expert's phase machine follows the episode (here, watching the policy carry the cube, it saw no
    phase's switch and is still in "approach"); at a takeover it resyncs to the state, so a cube the policy
    carries between closed fingers stays gripped (from "approach" it would open the gripper over it and
    teach the novice to drop it)."""
    op = ExpertOperator(SPEC, OperatorConfig(mode="gate", segment_steps=5, stall_steps=1))
    policy = np.zeros(7, np.float32)
    carried = _obs([0.5, 0.05, 0.15], obj=[0.5, 0.05, 0.14], opening=0.5)
    for _ in range(2):
        assert not op.act(carried, policy)[1]
        op.observe(0.0)
    action, by_op = op.act(carried, policy)
    # resynced to "lift", which at carrying height (0.15) moves on to "transfer" at once: gripper closed
    assert by_op and op.last_reason == "stalled" and op.expert.phase == "transfer" and action[6] == 1.0
    # Handed back and taken over again away from the cube (it fell): from above the cube, gripper open.
    op.left = 0
    op.since_progress = op.config.stall_steps
    action, by_op = op.act(_obs([0.45, 0.0, 0.2]), policy)
    assert by_op and op.expert.phase == "approach" and action[6] == -1.0


def test_always_and_off_modes_and_config_checks():
    always = ExpertOperator(SPEC, OperatorConfig(mode="always"))
    off = ExpertOperator(SPEC, OperatorConfig(mode="off"))
    obs, policy = _obs([0.45, 0.0, 0.5]), np.zeros(7, np.float32)
    assert all(always.act(obs, policy)[1] for _ in range(3)) and always.rate == 1.0 and always.takeovers == 0
    assert not any(off.act(obs, policy)[1] for _ in range(3)) and off.rate == 0.0
    for bad in (dict(mode="sometimes"), dict(segment_steps=0), dict(box=(0, 0, 0, 1, 1))):
        with pytest.raises(ValueError):
            OperatorConfig(**bad)
    with pytest.raises(ValueError, match="operator"):
        tasks.make("robot_pick_place", 1, 0, {"operator": "sometimes"})


def test_source_and_executed_action_travel_byte_exact_to_the_replay_batch():
    """Serial pool (workers in this process), random policy, gating operator: every transition the task
    emits is logged at the task; every row of a sampled replay batch (the trainer's field list) must be
    one of them, byte for byte in obs, executed action and source."""
    overrides = {"operator": "gate", "operator_stall_steps": 3, "operator_segment": 4, "episode_length": 30}
    pool = WorkerPool("robot_pick_place", overrides, num_workers=1, envs_per_worker=2, algo_module="robot_toy_algo",
                      weight_template={"w": np.zeros(1, np.float32)}, replay_capacity=2_000, serial=True)
    emitted: dict[bytes, tuple[bytes, int]] = {}
    with pool:
        pool.start()
        task = pool._serial_workers[0].task
        step = task.step

        def logged(action):
            obs_before = task._observe_all()[0]
            out = step(action)
            for i in range(task.num_envs):
                emitted[obs_before[i].tobytes()] = (out.extras["action"][i].tobytes(), int(out.extras["source"][i]))
            return out

        task.step = logged
        pool.publish({"w": np.zeros(1, np.float32)}, 1)
        pool.pump(150)
        fields = replay_fields(pool.spec)
        assert fields == REPLAY_FIELDS + ("source",)
        batch = pool.sample(256, np.random.default_rng(0), serial_steps=0)
        stats = pool.stats()
    batch = {k: batch[k] for k in fields}
    assert batch["source"].dtype == np.uint8
    sources = set()
    for i in range(256):
        action, source = emitted[batch["obs"][i].tobytes()]
        assert batch["action"][i].tobytes() == action and int(batch["source"][i]) == source
        sources.add(source)
    assert sources == {SOURCE_POLICY, SOURCE_OPERATOR}  # both kinds were sampled
    # Where the operator drove, the executed action is not the random policy's draw (|a| < 1 from tanh is
    # the policy's; the expert's gripper command is exactly +-1).
    op_rows = batch["source"] == SOURCE_OPERATOR
    assert np.all(np.abs(batch["action"][op_rows, 6]) == 1.0)
    # Per-episode intervention counters (10 episodes of 30 steps): rates in (0, 1], at least one takeover.
    metrics = stats["episode_metrics"]
    assert 0.0 < metrics["intervention_rate"] <= 1.0 and metrics["interventions"] >= 1.0


def test_late_fraction_is_the_share_of_an_episodes_steps_whose_action_came_late():
    """``late_fraction`` (the speed-1 runs' measure of a learner keeping up): env 0's robot reports every second
    action late; at the episode's last step (4) its metric is 2 / 4, env 1's 0, and the next episode counts anew."""
    task = tasks.make("robot_pick_place", 2, 0, {"episode_length": 4})
    try:
        calls = []
        step = task.robots[0].step

        def late_every_other(action):
            got = step(action)
            calls.append(len(calls) % 2 == 1)
            return got._replace(info={**got.info, "late": calls[-1]})

        task.robots[0].step = late_every_other
        task.reset()
        fractions = [task.step(np.zeros((2, task.spec.action_dim), np.float32)).extras["late_fraction"]
                     for _ in range(5)]
        assert [float(f[0]) for f in fractions] == [0.0, 0.5, pytest.approx(1 / 3), 0.5, 0.0]
        assert all(float(f[1]) == 0.0 for f in fractions)
        assert "late_fraction" in task.spec.episode_metrics
    finally:
        task.close()
