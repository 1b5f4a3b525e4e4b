"""``training/compile_cache.py``: JAX's persistent compilation cache as ``RunConfig.compilation_cache`` sets it, and the
launchers' and the Python API's checks of the option."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from script_helpers import run_in_process

import unilab_jax
from unilab_jax.training import compile_cache


@pytest.fixture
def cache_config(monkeypatch):
    """The process's cache settings restored afterwards (off, as the test suite runs)."""
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    min_time = jax.config.jax_persistent_cache_min_compile_time_secs
    yield
    compile_cache.configure("off", "jax")
    jax.config.update("jax_persistent_cache_min_compile_time_secs", min_time)


def test_auto_is_off_on_the_cpu_and_a_directory_keeps_the_programs_compiled_after(cache_config, tmp_path):
    assert jax.default_backend() == "cpu"
    assert compile_cache.configure("auto", "jax") == "" and jax.config.jax_compilation_cache_dir is None
    jax.jit(lambda x: x + 1)(jnp.ones(3))  # compiled while the cache is off: not kept

    path = str(tmp_path / "xla")
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)  # keep even this quick program
    assert compile_cache.configure(path, "jax") == path and os.path.isdir(path)
    assert os.listdir(path) == []
    out = jax.jit(lambda x: x * 3.0 - 1.0)(jnp.arange(4.0))
    np.testing.assert_allclose(out, [-1.0, 2.0, 5.0, 8.0])
    assert os.listdir(path), "the program compiled after the call was not cached"

    assert compile_cache.configure("off", "jax") == "" and jax.config.jax_compilation_cache_dir is None
    assert compile_cache.configure(path, "mlx") == ""  # MLX compiles nothing ahead
    assert jax.config.jax_compilation_cache_dir is None


def test_the_environment_variable_wins(cache_config, tmp_path, monkeypatch):
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "env"))
    assert compile_cache.configure(str(tmp_path / "flag"), "jax") == str(tmp_path / "env")
    assert not (tmp_path / "flag").exists()


def test_default_dir_follows_xdg_cache_home(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert compile_cache.default_dir() == str(tmp_path / "unilab_jax" / "xla")


def test_an_empty_setting_is_refused_before_anything_starts(tmp_path):
    out = run_in_process("ppo_cartpole.py", "--compilation_cache=", f"--logdir={tmp_path / 'run'}")
    assert out.returncode == 2 and "--compilation_cache=''" in out.stderr
    with pytest.raises(ValueError, match="compilation_cache"):
        unilab_jax.train("ppo", "cartpole_balance", logdir=str(tmp_path / "api"), total_steps=1000,
                         compilation_cache="")
