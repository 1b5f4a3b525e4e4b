"""bench/time_to_target.py: parsing a run's metrics, the report's ratios and bounds, and running a configuration
(a stand-in experiment script) until it reaches its goals (walking, and the return for Go1)."""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_spec = importlib.util.spec_from_file_location("time_to_target", os.path.join(ROOT, "bench", "time_to_target.py"))
ttt = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(ttt)


def _rows(evals, rate=1000.0, train_wall=None, walking=None):
    """Training rows every 10 s at ``rate`` env steps/s, plus eval rows (wall_s, return) with the walking numbers
    ``walking[i]`` (tracking, yaw rate, falls; default: a policy that stands still)."""
    rows = [{"step": int(rate * t), "perf/env_steps_per_s": rate, "time/wall_s": float(t), "loss/x": 0.0}
            for t in range(10, 110, 10)]
    for i, (wall, ret) in enumerate(evals):
        row = {"step": int(rate * wall), "eval/return": ret, "eval/wall_s": wall, "eval/done_wall_s": wall + 3,
               **dict(zip(("eval/tracking_error", "eval/yaw_rate_error", "eval/fall_rate"),
                          walking[i] if walking else (0.5, 0.45, 0.0)))}
        if train_wall is not None:
            row["eval/train_wall_s"] = train_wall[i]
        rows.append(row)
    return rows


def test_summarize_finds_first_eval_at_target():
    s = ttt.summarize(_rows([(20.0, 5.0), (40.0, 26.0), (60.0, 24.0), (80.0, 29.0)]), target=25.0)
    assert s["reached"] and s["time_to_target_s"] == 40.0 and s["env_steps_at_target"] == 40_000
    assert s["train_time_to_target_s"] == 40.0 and s["return_at_target"] == 26.0
    assert s["best_return"] == 29.0 and s["best_return_wall_s"] == 80.0
    assert s["env_steps_per_s_mean"] == pytest.approx(1000.0) and s["env_steps_per_s_median"] == 1000.0
    assert [e[3] for e in s["evals"]] == [5.0, 26.0, 24.0, 29.0]
    assert not s["walking_reached"] and s["time_to_walking_s"] is None  # it stood still
    # The MJX loop's evaluation-excluded clock is carried through.
    m = ttt.summarize(_rows([(30.0, 25.5)], train_wall=[21.0]), target=25.0)
    assert m["time_to_target_s"] == 30.0 and m["train_time_to_target_s"] == 21.0
    miss = ttt.summarize(_rows([(30.0, 10.0)]), target=25.0)
    assert not miss["reached"] and miss["time_to_target_s"] is None and miss["best_return"] == 10.0


def test_summarize_times_walking_by_the_criterion():
    """Walking is the first evaluation inside every bound: return alone (or planar tracking alone) is not enough."""
    walking = [(0.2, 0.5, 0.0),   # tracks planar velocity but not yaw rate
               (0.2, 0.2, 0.05),  # falls 5%
               (0.24, 0.28, 0.0),  # walks
               (0.1, 0.1, 0.0)]
    s = ttt.summarize(_rows([(20.0, 26.0), (40.0, 27.0), (60.0, 24.0), (80.0, 29.0)], walking=walking), target=25.0)
    assert s["time_to_target_s"] == 20.0 and s["walking_reached"] and s["time_to_walking_s"] == 60.0
    assert s["env_steps_at_walking"] == 60_000 and s["walking_at"]["yaw_rate_error"] == 0.28
    assert s["evals"][2][4:] == [0.24, 0.28, 0.0]
    # No return goal (Go2 / G1): only walking is timed.
    g = ttt.summarize(_rows([(20.0, 300.0), (40.0, 280.0)], walking=walking[1:3]), target=None)
    assert not g["reached"] and g["time_to_walking_s"] == 40.0
    assert not ttt.goals_reached(_rows([(20.0, 26.0)], walking=walking[:1]), 25.0)
    assert ttt.goals_reached(_rows([(20.0, 26.0), (40.0, 1.0)], walking=walking[1:3]), 25.0)
    assert not ttt.goals_reached(_rows([(20.0, 20.0), (40.0, 1.0)], walking=walking[1:3]), 25.0)
    assert ttt.goals_reached(_rows([(20.0, 20.0), (40.0, 1.0)], walking=walking[1:3]), None)


def test_metrics_reader_waits_for_complete_lines(tmp_path):
    path = tmp_path / "metrics.jsonl"
    reader = ttt.MetricsReader(str(path))
    assert reader.new_rows() == []
    with open(path, "w") as f:
        f.write('{"step": 1}\n{"step": ')
    assert reader.new_rows() == [{"step": 1}]
    with open(path, "a") as f:
        f.write('2}\n')
    assert reader.new_rows() == [{"step": 2}]


def _record(config, kind, sync, seed, time_s, reached=True, rate=1e5, train=None, budget=540.0):
    return {"config": config, "kind": kind, "sync": sync, "seed": seed, "target": 25.0, "max_seconds": budget,
            "reached": reached, "time_to_target_s": time_s if reached else None,
            "train_time_to_target_s": (train or time_s) if reached else None,
            "env_steps_at_target": 3e7 if reached else None, "env_steps_per_s_median": rate, "best_return": 26.0,
            "machine": {"gpus": ["NVIDIA H100 80GB HBM3, 81559 MiB, 550"], "cpus_usable": 16}}


def test_report_ratios_bounds_and_goals():
    records = [
        _record("ppo_lockstep", "heterogeneous", "lockstep", 0, 300.0, rate=6.5e4),
        _record("ppo_lockstep", "heterogeneous", "lockstep", 1, 340.0, rate=6.5e4),
        _record("appo_async", "heterogeneous", "async", 0, 180.0, rate=8e4),
        _record("appo_async", "heterogeneous", "async", 1, 200.0, rate=8e4),
        _record("mjx_ppo", "mjx", "lockstep", 0, 520.0, rate=5e5, train=400.0),
        _record("mjx_ppo", "mjx", "lockstep", 1, None, reached=False, rate=5e5),
    ]
    md, ratios = ttt.report(records)
    h = ratios["heterogeneous_vs_mjx_return"]
    assert h["heterogeneous"] == "appo_async" and h["mjx"] == "mjx_ppo"  # the fastest of each kind
    # mjx_ppo missed the target on seed 1: it counts at its 540 s budget, so its mean is a lower bound.
    assert h["speedup"] == pytest.approx(((520 + 540) / 2) / 190) and h["relation"] == ">="
    assert h["speedup_mjx_eval_excluded"] == pytest.approx(((400 + 540) / 2) / 190)
    assert not h["met"] and h["throughput_ratio"] == pytest.approx(8e4 / 5e5)
    a = ratios["async_vs_lockstep"]
    assert a["speedup"] == pytest.approx(320 / 190) and a["relation"] == "=" and a["met"]
    assert "| mjx_ppo | mjx | - | - | - | - | - | 2 (1) | >= 530 | 520, 540 |" in md  # no walking numbers
    assert "goal >= 1.5x: met" in md and "goal >= 3x: not met" in md and "at least 2.79x" in md
    assert "NVIDIA H100" in md
    # Choosing the configuration by name.
    _, named = ttt.report(records, het_best="ppo_lockstep")
    assert named["heterogeneous_vs_mjx_return"]["speedup"] == pytest.approx(530 / 320)
    assert "heterogeneous_vs_mjx_walking" not in named


def test_report_walking_goal_and_configs_without_a_return_target():
    go2 = {**_record("go2_flashsac", "heterogeneous", "async", 0, None, reached=False), "target": None,
           "walking_reached": True, "time_to_walking_s": 70.0, "train_time_to_walking_s": 70.0,
           "env_steps_at_walking": 9e6}
    go2_miss = {**go2, "seed": 1, "walking_reached": False, "time_to_walking_s": None}
    mjx = {**_record("mjx_ppo", "mjx", "lockstep", 0, 200.0), "walking_reached": True, "time_to_walking_s": 280.0,
           "train_time_to_walking_s": 250.0, "env_steps_at_walking": 9e7}
    md, ratios = ttt.report([go2, go2_miss, mjx])
    assert "| go2_flashsac | heterogeneous | 2 (1) | >= 305 | 70, 540 | >= 305 | 9.0M | - | - |" in md
    w = ratios["heterogeneous_vs_mjx_walking"]
    assert w["heterogeneous"] == "go2_flashsac" and w["relation"] == "<=" and w["speedup"] == pytest.approx(280 / 305)
    assert "heterogeneous_vs_mjx_return" not in ratios  # go2 has no return goal
    # A record from before the criterion is judged from its curve when that holds the walking numbers.
    old = {**_record("fastsac_async", "heterogeneous", "async", 0, 150.0),
           "evals": [[1e6, 100.0, 100.0, 20.0, 0.3, 0.2, 0.0], [2e6, 130.0, 130.0, 26.0, 0.2, 0.2, 0.0]]}
    agg = ttt.aggregate([old])["fastsac_async"]
    assert agg["walking"]["time_s"] == 130.0 and agg["return"]["time_s"] == 150.0


def test_report_separates_runs_of_one_configuration_at_different_commits():
    old = _record("fastsac_async", "heterogeneous", "async", 0, None, reached=False, rate=8e4)
    new = _record("fastsac_async", "heterogeneous", "async", 0, 160.0, rate=9e4)
    old["git_commit"], new["git_commit"] = "a" * 40, "b" * 40
    md, _ = ttt.report([old, new, _record("mjx_ppo", "mjx", "lockstep", 0, 200.0, rate=5e5)])
    assert "| fastsac_async @ aaaaaaa | heterogeneous | - | - | - | - | - | 1 (0) |" in md
    assert "| fastsac_async @ bbbbbbb | heterogeneous | - | - | - | - | - | 1 (1) | 160 |" in md
    # One commit only: the plain configuration name.
    md, _ = ttt.report([new, _record("mjx_ppo", "mjx", "lockstep", 0, 200.0, rate=5e5)])
    assert "| fastsac_async | heterogeneous |" in md


FAKE_EXPERIMENT = textwrap.dedent('''
    """Stands in for an experiment script: logs training rows and evaluations, then would run for minutes."""
    import argparse, json, os, time
    ap = argparse.ArgumentParser()
    ap.add_argument("--logdir")
    ap.add_argument("--seed", type=int)
    args, _ = ap.parse_known_args()
    os.makedirs(args.logdir, exist_ok=True)
    with open(os.path.join(args.logdir, "metrics.jsonl"), "a") as f:
        for i, ret in enumerate([3.0, 12.0, 27.0, 30.0]):
            step, wall = 1000 * (i + 1), i + 1.0
            f.write(json.dumps({"step": step, "perf/env_steps_per_s": 500.0, "time/wall_s": wall}) + "\\n")
            f.write(json.dumps({"step": step, "eval/return": ret + args.seed, "eval/wall_s": wall,
                                "eval/tracking_error": 0.2, "eval/yaw_rate_error": 0.6 - 0.1 * i,
                                "eval/fall_rate": 0.0}) + "\\n")
            f.flush()
            time.sleep(0.3)
    time.sleep(300)
''')


def test_run_one_stops_at_its_goals_and_appends(tmp_path):
    script = tmp_path / "fake_experiment.py"
    script.write_text(FAKE_EXPERIMENT)
    out = str(tmp_path / "results.json")
    args = ttt.parse_args(["--only", "mjx_ppo", "--max_seconds", "60", "--runs_dir", str(tmp_path / "runs"),
                           "--out", out])
    cfg = {"kind": "mjx", "sync": "lockstep", "script": str(script), "eval_every": 1000, "return_target": True}
    record = ttt.run_one("fake", 0, args, cfg=cfg, poll_s=0.1)
    # return 27 >= 25 at the 3rd evaluation, yaw-rate error 0.3 (walking) at the 4th: it runs on to both.
    assert record["stopped_by"] == "target" and record["reached"] and record["walking_reached"]
    assert record["time_to_target_s"] == 3.0 and record["env_steps_at_target"] == 3000
    assert record["time_to_walking_s"] == 4.0 and record["walking_criterion"]["max_yaw_rate_error"] == 0.3
    assert record["bench_wall_s"] < 30 and record["returncode"] is not None  # stopped, not waited out
    assert "--max_seconds=60.0" in record["command"] and "--seed=0" in record["command"]
    record.update(machine=ttt.machine_info(), git_commit=ttt.git_commit(), source_digest=ttt.source_digest())
    ttt.append(out, record)
    ttt.append(out, {**record, "seed": 1})
    data = json.load(open(out))
    assert [r["seed"] for r in data["records"]] == [0, 1]
    assert data["records"][0]["machine"]["cpus_usable"] >= 1 and len(data["records"][0]["source_digest"]) == 16


def test_stop_waits_its_grace_for_an_orderly_stop_then_kills():
    """A run that takes its time after SIGTERM (a trainer writing its replay rings) finishes within the grace; one
    that ignores SIGTERM is killed once the grace is over."""
    def launch(body):
        proc = subprocess.Popen([sys.executable, "-c", "import signal, sys, time\n" + body], start_new_session=True)
        time.sleep(0.5)  # the handler installed
        return proc

    slow = launch("signal.signal(signal.SIGTERM, lambda *a: (time.sleep(1.0), sys.exit(3)))\ntime.sleep(60)")
    ttt._stop(slow, grace=10.0)
    assert slow.returncode == 3  # its own exit, after the 1 s it took
    deaf = launch("signal.signal(signal.SIGTERM, signal.SIG_IGN)\ntime.sleep(60)")
    t0 = time.time()
    ttt._stop(deaf, grace=1.0)
    assert deaf.returncode == -signal.SIGKILL and time.time() - t0 < 5
    assert ttt.parse_args(["--only", "mjx_ppo"]).stop_grace == 30.0
    assert ttt.parse_args(["--only", "mjx_ppo", "--stop_grace", "90"]).stop_grace == 90.0


def test_cli_requires_a_configuration(capsys):
    with pytest.raises(SystemExit):
        ttt.parse_args([])
    with pytest.raises(SystemExit):
        ttt.parse_args(["--only", "no_such_config"])
    assert "unknown configurations" in capsys.readouterr().err


def test_command_sizes_heterogeneous_runs_per_config():
    """Off-policy configs default to 64 envs per worker, PPO/APPO to 128; --envs_per_worker overrides both;
    MJX runs get their own budget flag instead of worker flags."""
    def flags(name, argv=()):
        args = ttt.parse_args(["--only", name, *argv])
        return ttt.command(name, ttt.CONFIGS[name], 0, "/tmp/x", args)

    assert "--envs_per_worker=64" in flags("flashsac_async") and "--envs_per_worker=64" in flags("fastsac_async")
    assert "--envs_per_worker=128" in flags("ppo_lockstep")
    assert "--envs_per_worker=32" in flags("fastsac_async", ["--envs_per_worker", "32"])
    # Off-policy and Go2 / G1 configs evaluate 64 episodes (the falls bound allows one), PPO 32.
    assert "--eval_envs=64" in flags("go2_flashsac") and "--eval_envs=64" in flags("g1_fastsac")
    # the MJX baselines are judged on as many episodes as the off-policy runs they are compared with
    assert "--eval_envs=64" in flags("mjx_ppo") and "--eval_envs=64" in flags("fastsac_async")
    assert "--eval_envs=32" in flags("ppo_lockstep") and "--eval_envs=16" in flags("g1_fastsac", ["--eval_envs", "16"])
    assert flags("g1_fastsac")[1].endswith("experiments/fastsac_g1.py") and "--utd_mode=free" in flags("go2_flashsac")
    mjx = flags("mjx_ppo", ["--max_seconds", "100"])
    assert "--max_seconds=100.0" in mjx and not any(f.startswith("--num_workers") for f in mjx)


def test_rough_terrain_walking_criterion():
    """Rough configurations: walking counts only on an evaluation of levels >= half the top level (TerrainEval's
    terrain_level_min / terrain_level_top), falls <= 2%; the record holds the highest mean terrain level."""
    good = {"eval/tracking_error": 0.2, "eval/yaw_rate_error": 0.2, "eval/fall_rate": 0.0}
    assert ttt.is_walking({**good, "eval/terrain_level_min": 5.0, "eval/terrain_level_top": 9.0}, rough=True)
    assert ttt.is_walking({**good, "eval/terrain_level_min": 4.5, "eval/terrain_level_top": 9.0}, rough=True)
    assert not ttt.is_walking({**good, "eval/terrain_level_min": 4.0, "eval/terrain_level_top": 9.0}, rough=True)
    assert not ttt.is_walking(good, rough=True) and ttt.is_walking(good)  # flat rows carry no terrain levels
    assert not ttt.is_walking({**good, "eval/fall_rate": 0.03, "eval/terrain_level_min": 5.0,
                               "eval/terrain_level_top": 9.0}, rough=True)
    rows = _rows([(20.0, 1.0), (40.0, 1.0), (60.0, 1.0)], walking=[(0.2, 0.2, 0.0)] * 3)
    for row, low in zip((r for r in rows if "eval/return" in r), (3.0, 5.0, 6.0)):
        row.update({"eval/terrain_level_min": low, "eval/terrain_level_top": 9.0})
    for r, level in zip(rows[:10], (0.5, 1.0, 2.5, 4.0, 3.5, 6.0, 6.5, 6.2, 5.0, 6.1)):
        r["episode/terrain_level"] = level
        r.update({f"episode/terrain_level_{k}": float(k == round(level)) for k in range(10)})  # the histogram
    s = ttt.summarize(rows, None, rough=True)
    assert s["time_to_walking_s"] == 40.0 and ttt.summarize(rows, None)["time_to_walking_s"] == 20.0
    # averaged over the trailing 20 s (the row and the one 10 s before it) from 30 s on: 1.75, 3.25, 3.75, 4.75,
    # 6.25, 6.35 (80 s: (6.5 + 6.2) / 2), 5.6, 5.55; the single rows' 6.5 is not the population's
    assert s["max_terrain_level"] == pytest.approx(6.35)
    assert (s["max_terrain_level_wall_s"], s["max_terrain_level_step"]) == (80.0, 80_000)
    assert s["terrain_level_top"] == 9 and s["max_terrain_level_fraction"] == pytest.approx(6.35 / 9)
    assert ttt.goals_reached(rows, None, rough=True) and not ttt.goals_reached(rows[:11], None, rough=True)
    assert "--eval_envs=64" in ttt.command("g1_rough_fastsac", ttt.CONFIGS["g1_rough_fastsac"], 0, "/tmp/x",
                                           ttt.parse_args(["--only", "g1_rough_fastsac"]))
    mjx = ttt.command("mjx_go1_rough_ppo", ttt.CONFIGS["mjx_go1_rough_ppo"], 0, "/tmp/x",
                      ttt.parse_args(["--only", "mjx_go1_rough_ppo"]))
    assert "--task=go1_joystick_rough" in mjx and mjx[1].endswith("experiments/ppo_go1_mjx.py")


RESUMABLE_EXPERIMENT = textwrap.dedent('''
    """Stands in for a resumable experiment: the first process logs three evaluations short of the goals, keeps a
    checkpoint and would run for minutes; with --resume its clock goes on from 3 s and it walks at 5 s."""
    import argparse, json, os, time
    ap = argparse.ArgumentParser()
    ap.add_argument("--logdir")
    ap.add_argument("--seed", type=int)
    ap.add_argument("--resume", action="store_true")
    args, _ = ap.parse_known_args()
    os.makedirs(os.path.join(args.logdir, "checkpoints"), exist_ok=True)
    walls = [4.0, 5.0] if args.resume else [1.0, 2.0, 3.0]
    with open(os.path.join(args.logdir, "metrics.jsonl"), "a") as f:
        for wall in walls:
            step = int(1000 * wall)
            f.write(json.dumps({"step": step, "perf/env_steps_per_s": 500.0, "time/wall_s": wall}) + "\\n")
            f.write(json.dumps({"step": step, "eval/return": 30.0, "eval/wall_s": wall, "eval/tracking_error": 0.2,
                                "eval/yaw_rate_error": 0.2 if wall == 5.0 else 0.6, "eval/fall_rate": 0.0}) + "\\n")
            f.flush()
    time.sleep(300)
''')


def test_resume_continues_the_latest_run_and_the_report_counts_it_once(tmp_path):
    script = tmp_path / "resumable_experiment.py"
    script.write_text(RESUMABLE_EXPERIMENT)
    runs = str(tmp_path / "runs")
    cfg = {"kind": "heterogeneous", "sync": "async", "script": str(script), "eval_every": 1000,
           "return_target": False}
    first = ttt.run_one("fake", 0, ttt.parse_args(["--only", "fastsac_async", "--max_seconds", "2", "--runs_dir",
                                                   runs]), cfg=cfg, poll_s=0.1)
    assert first["stopped_by"] == "max_seconds" and not first["walking_reached"] and "--resume" not in first["command"]
    second = ttt.run_one("fake", 0, ttt.parse_args(["--only", "fastsac_async", "--max_seconds", "5", "--runs_dir",
                                                    runs, "--resume"]), cfg=cfg, poll_s=0.1)
    assert "--resume" in second["command"] and second["logdir"] == first["logdir"] and second["resumed"]
    # The whole run's rows, on its own clock: walking at 5 s of the run, whatever each process's start.
    assert second["stopped_by"] == "target" and second["time_to_walking_s"] == 5.0 and len(second["evals"]) == 5
    assert second["max_seconds"] == 5.0 and second["segment_max_seconds"] == 5.0
    other = {**first, "logdir": "/elsewhere", "seed": 1}
    assert ttt.final_records([first, other, second]) == [other, second]
    with pytest.raises(SystemExit):  # nothing to resume
        ttt.run_one("fake", 3, ttt.parse_args(["--only", "fastsac_async", "--runs_dir", runs, "--resume"]), cfg=cfg)
    with pytest.raises(SystemExit):  # the MJX loop keeps no checkpoint
        ttt.parse_args(["--only", "mjx_ppo", "--resume"])


def test_startup_reads_the_trainers_milestones():
    log = ("I1127 06:30:35.787 trainer.py:319] learner state ready 9.5 s after the start\n"
           "I1127 06:30:40.676 trainer.py:365] 13 workers started 14.4 s after the start\n"
           "[fastsac] eval 3.1 at 1,000,000 steps\n"
           "I1127 06:30:50.776 trainer.py:532] update compiled ahead of the first call in 15.0 s, 24.5 s after the "
           "start\n")
    assert ttt.startup(log) == {"learner_state_s": 9.5, "workers_started_s": 14.4, "update_compile_s": 15.0,
                                "update_compiled_s": 24.5}
    assert ttt.startup("no milestones here") == {}
