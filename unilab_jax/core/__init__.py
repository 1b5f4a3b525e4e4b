"""Pure algorithm kernels, written against the array-API shim only.

Every function here takes arrays (numpy, jax or mlx -- the backend is found from the inputs with
``unilab_jax.xp.namespace``) and returns arrays of the same backend; randomness enters as input
arrays (e.g. ``eps``), never through a global generator. Shapes are stated in each docstring; time
series are time-major ``[T, B]``. Import the modules you need::

    from unilab_jax.core import gae, vtrace, distributions, c51, normalizer, polyak, him
    from unilab_jax.core import ppo_losses as ppo
    from unilab_jax.core import sac_losses as sac
    from unilab_jax.core import td3_losses as td3
    from unilab_jax.core import adaptation as hora

Nothing is imported eagerly here, so ``import unilab_jax.core`` stays numpy-only and cheap.
"""
