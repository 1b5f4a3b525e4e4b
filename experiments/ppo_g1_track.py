"""PPO on G1 whole-body motion tracking (``g1_track``: squat, side step, turn, hop), sized for a 16-core + GPU machine.

    python experiments/ppo_g1_track.py --num_workers=15 --envs_per_worker=64 --logdir=runs/ppo_g1_track

BeyondMimic's PPO settings (rsl_rl): 512-256-128 ELU actor and critic, 24-step horizon, 5 epochs of 4
minibatches, lr 1e-3 with the KL-adaptive rule (target 0.01), gamma 0.99, lambda 0.95, entropy 0.005.
The actions are residuals on the reference's joint angles (target = reference + 0.5 * action), so the
initial policy std is small (exp(-1) = 0.37, i.e. +-0.18 rad of servo target): std 1 would throw the
servo targets half a radian off the clip at every step. Evaluations report ``eval/clip_completion`` (clips
played from their start to their end without termination) and ``eval/body_pos_error`` (m).
"""

from unilab_jax.cli import run_experiment

RECIPE = {"actor_hidden": (512, 256, 128), "critic_hidden": (512, 256, 128), "horizon": 24,
          "learning_rate": 1e-3, "num_epochs": 5, "num_minibatches": 4, "ent_coef": 0.005, "gamma": 0.99,
          "lam": 0.95, "desired_kl": 0.01, "init_log_std": -1.0}

if __name__ == "__main__":
    run_experiment(algo="ppo", task="g1_track", recipe=RECIPE, default_total_steps=100_000_000)
