"""``python -m unilab_jax.robots.record``: record demonstrations from robot servers.
The command keeps this documented name; the code is ``unilab_jax.apps.record``
(the applications wing, docs/ARCHITECTURE.md)."""

import sys

from unilab_jax.apps.record import main

if __name__ == "__main__":
    sys.exit(main())
