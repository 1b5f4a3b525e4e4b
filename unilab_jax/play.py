"""``python -m unilab_jax.play``: watch a trained policy.
The command keeps this documented name; the code is ``unilab_jax.apps.play``
(the applications wing, docs/ARCHITECTURE.md)."""

import sys

from unilab_jax.apps.play import main

if __name__ == "__main__":
    sys.exit(main())
