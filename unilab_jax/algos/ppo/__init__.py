"""PPO family: PPO, APPO (V-trace) and HIM-PPO declarations, their JAX learners and the MLX PPO/APPO learner."""
