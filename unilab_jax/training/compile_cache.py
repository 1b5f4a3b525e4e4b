"""JAX's persistent compilation cache for training runs (``RunConfig.compilation_cache``).

A JAX learner compiles its programs at every start: FastSAC Go1's update takes 10-13 s on the H100 machine, a fifth
of its time to walking (docs/perf/learner_scaling.md section 18). With the cache on, a run whose programs an earlier
run compiled (same shapes, config, JAX and device) loads them from disk instead. ``"auto"`` turns it on under
``$XDG_CACHE_HOME/unilab_jax/xla`` (``~/.cache/...``) when JAX computes on an accelerator, and leaves it off on the
CPU, where programs compile in a second or two and a test suite would fill the folder; a directory turns it on
there; ``"off"`` leaves it off. ``JAX_COMPILATION_CACHE_DIR`` in the environment (which JAX reads itself) wins: the
benchmarks give each run an empty one, so their times include the compiles.

JAX keeps only programs that took at least ``jax_persistent_cache_min_compile_time_secs`` (1 s) to compile. Nothing
prunes the folder (JAX's eviction needs the ``filelock`` package, not a dependency here): deleting it frees its space.
"""

from __future__ import annotations

import logging
import os

log = logging.getLogger(__name__)


def default_dir() -> str:
    """``$XDG_CACHE_HOME/unilab_jax/xla``, ``~/.cache/unilab_jax/xla`` without it."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "unilab_jax", "xla")


def check(setting: object, name: str = "compilation_cache") -> None:
    """Raises ``ValueError`` naming ``name`` unless ``setting`` is a valid value: "auto", "off" or a directory (a
    non-empty string)."""
    if not isinstance(setting, str) or not setting:
        raise ValueError(f"{name}={setting!r}: 'auto', 'off' or a directory")


def configure(setting: str, platform: str) -> str:
    """Applies ``setting`` ("auto", "off" or a directory) for a ``platform`` ("jax" or "mlx") learner; returns the
    directory programs are cached in ("" for none). Programs compiled before the call are not cached; later ones are,
    whatever compiled first (JAX reads the directory again at the next compile)."""
    if platform != "jax":
        return ""
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return os.environ["JAX_COMPILATION_CACHE_DIR"]
    if setting == "off" or (setting == "auto" and jax.default_backend() == "cpu"):
        path = ""
    else:
        path = default_dir() if setting == "auto" else os.path.abspath(os.path.expanduser(setting))
    if (jax.config.jax_compilation_cache_dir or "") == path:
        return path
    if path:
        try:
            os.makedirs(path, exist_ok=True)
        except OSError as e:  # a run goes on without the cache rather than not at all
            log.warning("compilation cache %s cannot be created (%s): programs compile at every start", path, e)
            path = ""
    jax.config.update("jax_compilation_cache_dir", path or None)
    compilation_cache.reset_cache()  # the next compile reads the directory again
    if path:
        log.info("compilation cache: %s", path)
    return path
