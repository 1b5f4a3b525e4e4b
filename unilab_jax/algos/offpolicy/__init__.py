"""Off-policy family: the SAC, TD3, FastSAC, FlashSAC, RLPD and SAC Flow declarations, DrQ-style image
observations for the SAC family (``image_obs``), their JAX and MLX learners and the scaffolding both share
(``learner_common``)."""
