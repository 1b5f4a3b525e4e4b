"""UniLab MLX backend: the shim's MLX namespace, MLX optimizers and state conversion.

The MLX learners live beside the JAX ones in each family folder (``unilab_jax/algos/<family>/learner_mlx.py``).
Importing this package never imports jax (a Mac user may not have it).
"""

from unilab_mlx import optim
from unilab_mlx.backend import MlxBackend

__all__ = ["MlxBackend", "optim"]
