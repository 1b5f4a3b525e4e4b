"""UniLab-JAX: heterogeneous robot RL (CPU MuJoCo workers, shared memory, JAX/MLX learners).

Importing this package imports numpy only; the JAX backend loads when asked for.
"""

__version__ = "0.1.0"
