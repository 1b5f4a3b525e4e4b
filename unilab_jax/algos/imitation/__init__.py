"""Imitation learning: behaviour cloning (``bc.py``, learner ``learner_jax.py``), the policy HG-DAgger trains
(``unilab_jax/training/hgdagger.py``)."""
