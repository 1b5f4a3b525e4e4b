"""UniLab MLX backend: the shim's MLX namespace, MLX optimizers and compiled learner steps.

Importing this package never imports jax (a Mac user may not have it).
"""

from unilab_mlx import optim
from unilab_mlx.backend import MlxBackend

__all__ = ["MlxBackend", "optim"]
