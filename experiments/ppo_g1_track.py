"""PPO on G1 whole-body motion tracking (``g1_track``: squat, side step, turn, hop), sized for a 16-core + GPU machine.

    python experiments/ppo_g1_track.py --num_workers=15 --envs_per_worker=128 --logdir=runs/ppo_g1_track

BeyondMimic's PPO settings (rsl_rl): 512-256-128 ELU actor and critic, 24-step horizon, 5 epochs of 4
minibatches, lr 1e-3 with the KL-adaptive rule (target 0.01), gamma 0.99, lambda 0.95, entropy 0.005.
The actions are residuals on the reference's joint angles (target = reference + s_j * action, s_j 0.125-0.62
rad), so the initial policy std is small (exp(-1) = 0.37, e.g. +-0.16 rad on a hip): std 1 would throw the
servo targets up to 0.6 rad off the clip at every step. On the 2-core VM (2 workers x 32 envs, 400k steps)
std exp(-1.5) reached the same episode lengths (61-67 vs 65-69 steps at the end, one seed each).
Evaluations report ``eval/clip_completion`` (clips played from their start to their end without
termination) and ``eval/body_pos_error`` (m). Networks, horizon, epochs, learning rate, gamma and lambda are
PPO's defaults; the recipe lists what differs.
"""

from unilab_jax import recipes
from unilab_jax.apps.cli import run_experiment

RECIPE = recipes.PPO_G1_TRACK

if __name__ == "__main__":
    run_experiment(**recipes.get("ppo_g1_track").kwargs)
