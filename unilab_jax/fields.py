"""Transition fields a learner's batch holds, by buffer kind (the trainer sends these; learners read them)."""

TRAJECTORY_FIELDS = ("obs", "critic_obs", "next_critic_obs", "action", "reward", "terminated", "truncated",
                     "log_prob", "mean", "log_std")  # [T, B, ...]
REPLAY_FIELDS = ("obs", "critic_obs", "action", "reward", "next_obs", "next_critic_obs", "terminated",
                 "truncated")  # [U, B, ...]
