"""Shared-memory segments: poison, attach without tracking, creator-only unlink, stale cleanup."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from multiprocessing import resource_tracker, shared_memory
from unittest import mock

import numpy as np
import pytest

from unilab_jax.runtime import shm as shm_mod
from unilab_jax.runtime.shm import SharedArrays, ShmSpaceError, cleanup_stale, list_segments

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
LAYOUT = {
    "f": ((3, 5), np.float32),
    "d": ((2,), np.float64),
    "i": ((7,), np.int64),
    "j": ((), np.int32),
    "u": ((4,), np.uint8),
    "b": ((6,), bool),
    "z": ((0, 4), np.float32),
}


def test_create_poisons_aligns_and_attaches():
    with SharedArrays.create(LAYOUT, tag="test") as seg:
        assert seg.name.startswith(f"unilab_{os.getpid()}_") and seg.name.endswith("_test")
        assert len(seg.name) <= 30  # macOS limits POSIX shm names to 31 characters (with the '/')
        assert np.isnan(seg["f"]).all() and np.isnan(seg["d"]).all()
        assert (seg["i"] == -1).all() and seg["j"] == -1
        assert (seg["u"] == 255).all() and seg["b"].all()
        assert all(off % 64 == 0 for off in seg.offsets.values())
        # the padding between fields (it enters slot checksums) reads as zeros: every byte outside the fields
        poisoned = np.zeros(len(seg.raw), bool)
        for name, off in seg.offsets.items():
            poisoned[off:off + seg[name].nbytes] = True
        assert (~poisoned).sum() > 0 and not np.frombuffer(seg.raw, np.uint8)[~poisoned].any()
        for name, (shape, dtype) in LAYOUT.items():
            assert seg[name].shape == shape and seg[name].dtype == np.dtype(dtype)
        seg["f"][1, 2] = 7.0
        other = SharedArrays.attach(seg.handle)
        assert other["f"][1, 2] == 7.0  # same memory
        other["i"][3] = 42
        assert seg["i"][3] == 42
        other.close()
        assert os.path.exists(f"/dev/shm/{seg.name}"), "an attacher must never unlink"
    assert not os.path.exists(f"/dev/shm/{seg.name}"), "the creator unlinks on close"


def test_attach_does_not_register_with_resource_tracker():
    with SharedArrays.create({"x": ((4,), np.float32)}) as seg:
        with mock.patch.object(resource_tracker, "register", wraps=resource_tracker.register) as reg:
            att = SharedArrays.attach(seg.handle)
            att.close()
        assert not [c for c in reg.call_args_list if c.args[1:] == ("shared_memory",)]


def test_attach_from_unrelated_process_leaves_segment_alive():
    """Python 3.11's tracker unlinks segments an attaching process registered when it exits."""
    with SharedArrays.create({"x": ((4,), np.float32)}) as seg:
        seg["x"][:] = 3.0
        code = textwrap.dedent(f"""
            import sys; sys.path.insert(0, {REPO!r})
            from unilab_jax.runtime.shm import SharedArrays, ShmHandle
            h = ShmHandle({seg.name!r}, (("x", (4,), "<f4"),))
            s = SharedArrays.attach(h)
            assert float(s["x"].sum()) == 12.0
            s["x"][0] = 5.0
            s.close()
        """)
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        assert "leaked" not in proc.stderr and "resource_tracker" not in proc.stderr, proc.stderr
        assert os.path.exists(f"/dev/shm/{seg.name}")
        assert seg["x"][0] == 5.0


def test_cleanup_stale_removes_only_dead_creators():
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    name = f"unilab_{dead.pid}_deadbeef_x"
    raw = shared_memory.SharedMemory(name=name, create=True, size=64)
    resource_tracker.unregister(raw._name, "shared_memory")  # as if its whole process tree was killed
    raw.close()
    with SharedArrays.create({"x": ((4,), np.float32)}) as live:
        assert name in list_segments()
        assert cleanup_stale(dry_run=True) == [name] or name in cleanup_stale(dry_run=True)
        removed = cleanup_stale()
        assert name in removed
        assert live.name not in removed
        assert name not in list_segments() and live.name in list_segments()


def test_clear_error_when_dev_shm_is_too_small():
    free = os.statvfs("/dev/shm").f_bavail * os.statvfs("/dev/shm").f_frsize
    ours = f"unilab_{os.getpid()}_"  # other test processes (pytest-xdist) create segments meanwhile
    before = set(list_segments(ours))
    with pytest.raises(ShmSpaceError, match="MiB"):
        SharedArrays.create({"x": ((free // 4 + (1 << 28),), np.float32)})
    assert set(list_segments(ours)) == before


def test_fallocate_failure_is_a_clear_error_and_unlinks(monkeypatch):
    def no_room(fd, off, n):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(shm_mod.os, "posix_fallocate", no_room)
    ours = f"unilab_{os.getpid()}_"
    before = set(list_segments(ours))
    with pytest.raises(ShmSpaceError, match="ran out of space"):
        SharedArrays.create({"x": ((1024,), np.float32)})
    assert set(list_segments(ours)) == before


def test_runtime_and_worker_imports_never_load_jax():
    code = textwrap.dedent(f"""
        import sys; sys.path.insert(0, {REPO!r})
        import unilab_jax.runtime, unilab_jax.runtime.worker, unilab_jax.runtime.pool, tasks
        tasks.make("cartpole_balance", 2, 0).step(__import__("numpy").zeros((2, 1), "float32"))
        bad = sorted(m for m in sys.modules if m == "jax" or m.startswith(("jax.", "jaxlib")))
        assert not bad, bad
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
