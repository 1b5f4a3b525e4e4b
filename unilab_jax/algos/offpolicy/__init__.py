"""Off-policy family: SAC, TD3, FastSAC and FlashSAC declarations, their JAX and MLX learners and the
scaffolding both share (``learner_common``)."""
