"""``python -m unilab_jax.web``: build a static page that drives an exported policy in the browser.
The command keeps this documented name; the code is ``unilab_jax.apps.web``
(the applications wing, docs/ARCHITECTURE.md)."""

import sys

from unilab_jax.apps.web import main

if __name__ == "__main__":
    sys.exit(main())
