"""Imports every built-in task module so each registers itself."""

import tasks.cartpole  # noqa: F401
import tasks.g1_walk  # noqa: F401
import tasks.go1_joystick  # noqa: F401
import tasks.go2_joystick  # noqa: F401
import tasks.history  # noqa: F401  (after the others: registers the ``_hist`` variants of the tasks above)
