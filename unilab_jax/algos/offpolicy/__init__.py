"""Off-policy family: the SAC, TD3, FastSAC, FlashSAC, RLPD and SAC Flow declarations (``OffPolicyConfig`` in
``base_config``, the pieces they share in ``shared``), DrQ-style image observations for the SAC family
(``image_obs``), their JAX and MLX learners and the scaffolding both share (``learner_common``, with the order of
a gradient step written once)."""
