"""toy_algo, asynchronous (workers never wait for new weights)."""

from toy_algo import act, extras, init_weights  # noqa: F401

SYNC = "async"
BUFFER = "trajectory"
