"""The applications wing: what a user runs on top of the training wing.

* ``cli``: the flags every experiment script shares and ``run_experiment``; the family command lines on top of
  it: ``hora_cli`` (two-stage HORA), ``mjx_cli`` (the MJX experiments), ``robot_cli`` (robots as resources).
* ``play`` / ``export`` / ``record``: watch a trained policy, export it for on-robot inference, record
  demonstrations through robot servers (``python -m unilab_jax.play``, ``python -m unilab_jax.export`` and
  ``python -m unilab_jax.robots.record`` forward here).
* ``saved_run``: a run read back from its logdir, the policy ``play`` and ``export`` use.

Importing the package itself imports nothing.
"""
