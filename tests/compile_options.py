"""XLA options for the programs the tests compile themselves (``compiler_options`` of ``jax.jit``, the learners,
the MJX trainers): LLVM at -O0 and XLA's classic CPU emitters instead of its fusion emitters. Measured on the
2-core VM, CPU seconds of a whole file with the first option alone -> both: tests/test_mjx_training.py 113 -> 71,
tests/tasks/test_mjx_walking_parity.py 90 -> 59, tests/algos/test_compute_dtype.py 29 -> 15 (the Go1 MJX step
compiles in 14 instead of 23); the tolerances of every parity test hold unchanged. Experiment scripts started
by the tests compile with XLA's defaults, as a user's run does."""

FAST_COMPILE = {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}
