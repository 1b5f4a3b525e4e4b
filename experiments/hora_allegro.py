"""HORA on Allegro in-hand rotation, its own task: a teacher that reads the object's parameters (mass,
centre of mass, friction, size, shape) and state (position, orientation, velocities), then a student that
infers them from 30 frames of proprioceptive history; one command (see unilab_jax/apps/hora_cli.py). The two
are compared on rotation rate.

    python experiments/hora_allegro.py --num_workers=15 --envs_per_worker=64 --teacher_steps=60000000 \\
        --student_steps=10000000 --logdir=runs/hora_allegro
    python experiments/hora_allegro.py --logdir=runs/hora_allegro --resume   # continues the stage that was cut off
"""

from ppo_allegro_rotate import RECIPE as PPO_RECIPE
from ppo_allegro_rotate import TASK_RECIPE as PPO_TASK_RECIPE

from unilab_jax.apps.hora_cli import run_hora

# Rotation and fall terms only and the object's state in the extrinsics, as the PPO recipe; but the frames stay
# proprioceptive (the student's history must not hold the extrinsics): the teacher sees them through z only
# (the history variant appends them after the frames: history_extrinsics, its default).
TASK_RECIPE = {**PPO_TASK_RECIPE, "actor_extrinsics": False}
TEACHER_RECIPE = PPO_RECIPE  # HORA's encoder (256, 128) and 8-dim z are hora_teacher's defaults
STUDENT_RECIPE = {"horizon": 16}  # else hora_student's defaults: lr 1e-3, 2 epochs x 4 minibatches

if __name__ == "__main__":
    run_hora(task="allegro_rotate_hist", teacher_recipe=TEACHER_RECIPE, student_recipe=STUDENT_RECIPE,
             task_recipe=TASK_RECIPE, default_teacher_steps=60_000_000, default_student_steps=10_000_000,
             compare_metric="rotation_rate")
