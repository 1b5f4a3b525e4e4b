"""The training wing: the loops that train a policy, and their parts.

* ``trainer``: the loop on the heterogeneous runtime (rollout workers on CPU MuJoCo, shared memory, a JAX or
  MLX learner), for on- and off-policy algorithms; its parts: ``sources`` (trajectory slots or replay
  minibatches), ``threads`` (learner and prefetch threads, stop signals), ``evaluation`` (deterministic
  episodes, background evaluations and clips), ``device_replay`` (the replay rings mirrored in accelerator
  memory) and ``sharding`` (data-parallel learners over local devices).
* ``mjx``: the GPU-resident loops on the MJX tasks (the baseline of ``bench/time_to_target.py``).
* ``hgdagger``: HG-DAgger's round-based imitation loop on robot tasks.

The parts never import the loops (tests/test_layers.py). Importing the package itself imports nothing.
"""
