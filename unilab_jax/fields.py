"""Transition fields a learner's batch holds, by buffer kind (the trainer sends these; learners read them)."""

TRAJECTORY_FIELDS = ("obs", "critic_obs", "next_critic_obs", "action", "reward", "terminated", "truncated",
                     "log_prob", "mean", "log_std")  # [T, B, ...]
REPLAY_FIELDS = ("obs", "critic_obs", "action", "reward", "next_obs", "next_critic_obs", "terminated",
                 "truncated")  # [U, B, ...]


def replay_fields(spec: object) -> tuple[str, ...]:
    """The replay batch of a task: ``REPLAY_FIELDS`` and the task's own ``transition_fields`` (e.g. the robot
    tasks' ``source``), which learners that do not read them ignore."""
    return REPLAY_FIELDS + tuple(name for name, _, _ in getattr(spec, "transition_fields", ()))


# A task with an image observation (``spec.image_shape``) adds these transition fields: uint8 ``[..., H, W, C]``,
# the images of ``obs`` and of ``next_obs`` (before auto-reset).
IMAGE_FIELDS = ("image", "next_image")


def prior_fields(spec: object) -> tuple[str, ...]:
    """The fields of prior data (demonstrations) for a task: ``REPLAY_FIELDS`` and, on tasks with images,
    ``IMAGE_FIELDS`` (not the task's other fields, such as the robot tasks' ``source``)."""
    return REPLAY_FIELDS + (IMAGE_FIELDS if getattr(spec, "image_shape", ()) else ())
