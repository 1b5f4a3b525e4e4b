"""toy_algo on per-worker replay rings, asynchronous."""

from toy_algo import act, extras, init_weights  # noqa: F401

SYNC = "async"
BUFFER = "replay"
