"""The robot experiments evaluate on robots their workers never trained on: the policy's observation must not
tell those robots apart. With the inventory-slot one-hot, an evaluation robot's slot column has variance 0 in
the training statistics and reaches the policy at the normaliser's clip bound (RLPD peg on an H100, 12 robots,
8 training and 4 evaluating: eval success 0-0.25 over 60 robot-minutes while the in-process loop reached
0.62-0.88)."""

from __future__ import annotations

import numpy as np

import tasks
from unilab_jax import xp as shim
from unilab_jax.apps import record
from unilab_jax.apps.robot_cli import ROBOT_TASK, STATE_TASK
from unilab_jax.core import normalizer

PEG = ("--robot=franka", "--task=peg_insertion", "--speed=50", "--reset_s=0.1", "--cameras=none", "--dense_reward")
NP = shim.get("numpy")


def _train_and_eval_obs(robots: tuple[str, ...], overrides: dict) -> tuple[np.ndarray, np.ndarray, int]:
    """Observations of a training task (claims the first robot, 10 random steps) and of an evaluation task
    (claims the robot left free), and the column where the kind one-hot starts."""
    ov = {**overrides, "robots": robots, "timeout_s": 1.0}
    train = tasks.make("robot_peg_insertion", 1, seed=0, overrides=ov)
    ev = tasks.make("robot_peg_insertion", 1, seed=1, overrides=ov)
    try:
        assert (train.slots, ev.slots) == ([0], [1])
        rows = [train.reset()[0]]
        rng = np.random.default_rng(0)
        for _ in range(10):
            rows.append(train.step(rng.uniform(-1, 1, (1, train.spec.action_dim)).astype(np.float32)).obs)
        spec = train.robot_spec
        return np.concatenate(rows), ev.reset()[0], spec.proprio_dim + spec.privileged_dim
    finally:
        train.close()
        ev.close()


def test_the_experiments_policy_cannot_tell_an_evaluation_robot_from_a_training_one(serve):
    robots = tuple(serve(*PEG).address for _ in range(2))
    recipe = {**ROBOT_TASK, **STATE_TASK}  # what robot_cli gives every robot experiment's task (state-based here)
    for identity in (True, False):
        train, ev, tail = _train_and_eval_obs(robots, {**recipe, "robot_identity": identity})
        stats = normalizer.stats_update(normalizer.stats_init(train.shape[1], NP), train)
        z = np.asarray(normalizer.normalize(stats, ev))
        if identity:  # kind (2) + slot (2) columns: the evaluation robot's slot was never seen in training
            assert ev.shape[1] == tail + 4 and ev[0, tail + 3] == 1.0 and train[:, tail + 3].max() == 0.0
            assert z[0, tail + 3] == 10.0  # normalised to the clip bound: out of what the policy learnt on
        else:  # kind only: the same columns, the same values on every robot of the inventory
            assert ev.shape[1] == train.shape[1] == tail + 2
            assert (train[:, tail:] == ev[0, tail:]).all()
            np.testing.assert_array_equal(z[:, tail:], 0.0)


def test_recorded_demonstrations_have_the_experiments_layout():
    """``python -m unilab_jax.robots.record`` records for the robot experiments: no slot one-hot unless asked."""
    assert record.task_overrides(record.parse_args(["--out=x"]))["robot_identity"] is ROBOT_TASK["robot_identity"]
    assert record.task_overrides(record.parse_args(["--out=x", "--robot_identity"]))["robot_identity"] is True
