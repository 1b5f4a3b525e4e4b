"""SAC on peg insertion through robot servers, without prior data: the baseline of ``rlpd_franka_peg.py``.

    python experiments/sac_franka_peg.py --speed=20 --total_steps=2000 --logdir=runs/sac_peg

Same networks, observations (``policy_state``), reward (success only), batch and update-to-data ratio as
``rlpd_franka_peg.py``; SAC's twin critics and no demonstrations. Flags beside the shared ones: ``unilab_jax.robot_cli``.
"""

from unilab_jax.robot_cli import run_robot_experiment

RECIPE = {"actor_hidden": (128, 128), "critic_hidden": (128, 128), "batch_size": 128, "updates_per_call": 16,
          "publish_every": 16, "utd": 4.0, "learning_starts": 300, "replay_capacity": 200_000, "gamma": 0.95}
TASK = {"policy_state": True}

if __name__ == "__main__":
    run_robot_experiment("sac", "robot_peg_insertion", RECIPE, default_total_steps=36_000, task_recipe=TASK,
                         dense_reward=False)
