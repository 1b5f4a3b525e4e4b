"""``python -m unilab_jax.export``: export a trained policy for on-robot inference.
The command keeps this documented name; the code is ``unilab_jax.apps.export``
(the applications wing, docs/ARCHITECTURE.md)."""

import sys

from unilab_jax.apps.export import main

if __name__ == "__main__":
    sys.exit(main())
