"""``runtime/durable.py``: an atomic write replaces a file whole or not at all."""

from __future__ import annotations

import os

import pytest

from unilab_jax.runtime.durable import durable_file, fsync_dir, write_atomic


def test_write_atomic_replaces_whole_or_leaves_the_old_content(tmp_path):
    path = str(tmp_path / "index.json")
    write_atomic(path, lambda f: f.write("old"), binary=False)
    assert open(path).read() == "old" and os.listdir(tmp_path) == ["index.json"]

    def fail(f):
        f.write("half of the new")
        raise RuntimeError("disk gone")

    with pytest.raises(RuntimeError):
        write_atomic(path, fail, binary=False)
    assert open(path).read() == "old" and os.listdir(tmp_path) == ["index.json"]  # no temporary file left
    write_atomic(path, lambda f: f.write(b"\x00new"), binary=True, suffix=".part")
    assert open(path, "rb").read() == b"\x00new"


def test_durable_file_writes_through_and_a_folder_fsyncs(tmp_path):
    with durable_file(str(tmp_path / "a.bin")) as f:
        f.write(b"abc")
    assert (tmp_path / "a.bin").read_bytes() == b"abc"
    fsync_dir(str(tmp_path))
