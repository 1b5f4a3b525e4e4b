"""Transition fields a learner's batch holds, by buffer kind (the trainer sends these; learners read them)."""

TRAJECTORY_FIELDS = ("obs", "critic_obs", "next_critic_obs", "action", "reward", "terminated", "truncated",
                     "log_prob", "mean", "log_std")  # [T, B, ...]
REPLAY_FIELDS = ("obs", "critic_obs", "action", "reward", "next_obs", "next_critic_obs", "terminated",
                 "truncated")  # [U, B, ...]


def replay_fields(spec: object) -> tuple[str, ...]:
    """The replay batch of a task: ``REPLAY_FIELDS`` and the task's own ``transition_fields`` (e.g. the robot
    tasks' ``source``), which learners that do not read them ignore."""
    return REPLAY_FIELDS + tuple(name for name, _, _ in getattr(spec, "transition_fields", ()))
