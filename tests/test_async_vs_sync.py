"""bench/async_vs_sync.py without robots: its flags (a list of sync update-to-data ratios) and the speed-ups it
reports, one per sync run against the same policy's async run."""

from __future__ import annotations

import importlib.util
import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def avs():
    sys.path.insert(0, os.path.join(ROOT, "bench"))  # the script imports its sibling time_to_target
    try:
        spec = importlib.util.spec_from_file_location("async_vs_sync", os.path.join(ROOT, "bench", "async_vs_sync.py"))
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.path.remove(os.path.join(ROOT, "bench"))


def test_utd_list_and_bad_values(avs, capsys):
    assert avs.parse_args([]).utd == [1.0]
    assert avs.parse_args(["--utd=1,2.5,4"]).utd == [1.0, 2.5, 4.0]
    for bad in ("0", "1,-2", "a", ","):
        with pytest.raises(SystemExit):
            avs.parse_args([f"--utd={bad}"])
        assert "--utd" in capsys.readouterr().err


def test_speedups_pair_each_sync_run_with_its_policys_async_run(avs):
    def row(policy, mode, utd, collect, train):
        return {"policy": policy, "mode": mode, "utd": utd, "collection_s_per_episode": collect,
                "training_s_per_update": train}

    results = [row("sac_cnn", "async", None, 13.0, 0.04), row("sac_cnn", "sync", 1.0, 15.0, 0.3),
               row("sac_cnn", "sync", 4.0, 20.0, 0.1), row("sacflow_large", "async", None, 13.0, 0.01),
               row("sacflow_large", "sync", 1.0, 13.0, 0.26), row("sac", "sync", 1.0, 12.0, 0.2)]
    out = avs.speedups(results)
    assert [(r["policy"], r["utd"]) for r in out] == [("sac_cnn", 1.0), ("sac_cnn", 4.0), ("sacflow_large", 1.0)]
    assert out[1]["collection"] == pytest.approx(20.0 / 13.0) and out[1]["training"] == pytest.approx(0.1 / 0.04)
    assert out[2]["collection"] == pytest.approx(1.0) and out[2]["training"] == pytest.approx(26.0)
