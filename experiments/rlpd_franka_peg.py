"""RLPD on peg insertion through robot servers, with 20 demonstrations (robots as resources, docs/ROBOTS.md).

    python experiments/rlpd_franka_peg.py --speed=20 --total_steps=2000 --logdir=runs/rlpd_peg
    python experiments/rlpd_franka_peg.py --robots=sim:franka_emika_panda,sim:franka_emika_panda \\
        --demos=demos/peg --eval_every=1000 --eval_envs=1 --num_workers=1 --config utd=20

Without ``--demos`` the scripted expert records ``--num_demos`` (20) episodes on the run's robots first
(``LOGDIR/demos``). Each minibatch is half demonstrations, half online data (symmetric sampling), the
critics a LayerNorm ensemble of 10 with a subset-of-2 min target. The policy sees proprioception and the
robot's privileged object state (``policy_state``: the state-based stand-in for the cameras). Reward: 1 on
success only (the episode then ends), as a physical robot's success detector gives it (``--dense_reward``
adds the shaped term). Flags beside the shared ones: ``unilab_jax.robot_cli``. The recipe's ``utd`` (4)
fits a CPU; the paper's 20 suits a GPU.
"""

from unilab_jax.robot_cli import run_robot_experiment

RECIPE = {"actor_hidden": (128, 128), "critic_hidden": (128, 128), "batch_size": 128, "updates_per_call": 16,
          "publish_every": 16, "utd": 4.0, "learning_starts": 300, "replay_capacity": 200_000, "gamma": 0.95}
TASK = {"policy_state": True}

if __name__ == "__main__":
    run_robot_experiment("rlpd", "robot_peg_insertion", RECIPE, default_total_steps=36_000, task_recipe=TASK,
                         dense_reward=False)
