"""RLPD on peg insertion through robot servers, with 20 demonstrations (robots as resources, docs/ROBOTS.md).

    python experiments/rlpd_franka_peg.py --speed=20 --total_steps=2000 --logdir=runs/rlpd_peg
    python experiments/rlpd_franka_peg.py --robots=sim:franka_emika_panda,sim:franka_emika_panda \\
        --demos=demos/peg --eval_every=1000 --eval_envs=1 --num_workers=1 --config utd=20
    python experiments/rlpd_franka_peg.py --algo=rlpd_flow --speed=20 --total_steps=2000 --logdir=runs/rlpdflow_peg

Without ``--demos`` the scripted expert records ``--num_demos`` (20) episodes on the run's robots first
(``LOGDIR/demos``, with the run's images). Each minibatch is half demonstrations, half online data (symmetric
sampling), the critics a LayerNorm ensemble of 10 with a subset-of-2 min target. The policy sees proprioception
and the front and wrist cameras' last 2 frames (``--observation=images``, the default: uint8 frame stacks rendered
by the robots, a DrQ encoder trained by the critic, which reads the same and no object pose; ``--asymmetric``: the
critic also reads the privileged state, the actor has its own encoder; ``--observation=state``: the robot's
privileged object state instead, the state-based comparison). Reward: 1 on
success only (the episode then ends), as a physical robot's success detector gives it (``--dense_reward``
adds the shaped term). ``--algo=rlpd_flow``: the same with SAC Flow's gated flow actor
(``unilab_jax/algos/offpolicy/rlpdflow.py``). Flags and recipe: ``unilab_jax.apps.robot_cli``.
"""

from unilab_jax import recipes
from unilab_jax.apps.robot_cli import run_robot_experiment

if __name__ == "__main__":
    run_robot_experiment(**recipes.get("rlpd_franka_peg").kwargs)
