"""HORA on Go1 joystick flat: a teacher that reads the domain-randomisation parameters, then a student
that infers them from 30 frames of proprioceptive history; one command (see unilab_jax/apps/hora_cli.py).

    python experiments/hora_go1.py --num_workers=15 --envs_per_worker=128 --teacher_steps=40000000 \\
        --student_steps=10000000 --logdir=runs/hora_go1
    python experiments/hora_go1.py --logdir=runs/hora_go1 --resume   # continues the stage that was cut off

Sized for a 16-core H100 host (15 workers x 128 envs, as above; the flag defaults are 2 x 32).
"""

from ppo_go1 import RECIPE as PPO_RECIPE

from unilab_jax.apps.hora_cli import run_hora

# Go1's extrinsics (tasks/go1_joystick.py): floor friction, joint friction loss, armature, torso COM,
# link masses, torso mass, default-pose offset and (enabled here, +-10%) motor strength: 66 numbers.
TASK_RECIPE = {"history_extrinsics": True, "dr_motor_strength": (0.9, 1.1)}
TEACHER_RECIPE = {**PPO_RECIPE, "encoder_hidden": (256, 128), "z_dim": 8}  # HORA's encoder, 8-dim z
STUDENT_RECIPE = {"horizon": 24, "learning_rate": 1e-3, "num_epochs": 2, "num_minibatches": 4}

if __name__ == "__main__":
    run_hora(task="go1_joystick_flat_hist", teacher_recipe=TEACHER_RECIPE, student_recipe=STUDENT_RECIPE,
             task_recipe=TASK_RECIPE, default_teacher_steps=40_000_000, default_student_steps=10_000_000)
