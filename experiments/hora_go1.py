"""HORA on Go1 joystick flat: a teacher that reads the domain-randomisation parameters, then a student
that infers them from 30 frames of proprioceptive history; one command (see unilab_jax/apps/hora_cli.py).

    python experiments/hora_go1.py --num_workers=15 --envs_per_worker=128 --teacher_steps=40000000 \\
        --student_steps=10000000 --logdir=runs/hora_go1
    python experiments/hora_go1.py --logdir=runs/hora_go1 --resume   # continues the stage that was cut off

Sized for a 16-core H100 host (15 workers x 128 envs, as above; the flag defaults are 2 x 32).
"""

from ppo_go1 import RECIPE as PPO_RECIPE

from unilab_jax.apps.hora_cli import run_hora

# Go1's extrinsics (tasks/go1_joystick.py; the history variant appends them after the frames by default): floor
# friction, joint friction loss, armature, torso COM, link masses, torso mass, default-pose offset and (enabled
# here, +-10%) motor strength: 66 numbers.
TASK_RECIPE = {"dr_motor_strength": (0.9, 1.1)}
TEACHER_RECIPE = PPO_RECIPE  # HORA's encoder (256, 128) and 8-dim z are hora_teacher's defaults
STUDENT_RECIPE = {}  # hora_student's defaults: 24-step horizon, lr 1e-3, 2 epochs x 4 minibatches

if __name__ == "__main__":
    run_hora(task="go1_joystick_flat_hist", teacher_recipe=TEACHER_RECIPE, student_recipe=STUDENT_RECIPE,
             task_recipe=TASK_RECIPE, default_teacher_steps=40_000_000, default_student_steps=10_000_000)
