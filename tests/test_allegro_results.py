"""bench/allegro_results.py: records read from run logdirs, one per (setting, role, seed) (a rerun replaces its
record), the report's means and goal verdicts, and bad --run arguments refused with exit 2."""

from __future__ import annotations

import importlib.util
import json
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_spec = importlib.util.spec_from_file_location("allegro_results", os.path.join(ROOT, "bench", "allegro_results.py"))
ar = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(ar)


def _run(path, rates, ttf=0.9, steps=4_000_000):
    """A logdir with evaluations at ``rates`` (the last one the summary's)."""
    os.makedirs(path)
    with open(os.path.join(path, "metrics.jsonl"), "w") as f:
        f.write(json.dumps({"step": 10, "loss/x": 1.0}) + "\n")
        for i, r in enumerate(rates):
            f.write(json.dumps({"step": (i + 1) * 1000, "eval/rotation_rate": r, "eval/time_to_fall": ttf}) + "\n")
    with open(os.path.join(path, "summary.json"), "w") as f:
        json.dump({"env_steps": steps, "wall_s": 400.0, "interrupted": False, "eval/rotation_rate": rates[-1],
                   "eval/rotation_rate_se": 0.01, "eval/time_to_fall": ttf, "eval/rotate_reward": rates[-1] / 2,
                   "eval/episodes": 128.0}, f)
    return str(path)


def test_records_replace_by_setting_role_seed_and_report_the_goal(tmp_path, capsys):
    out = str(tmp_path / "allegro.json")
    teacher = [_run(tmp_path / f"t{s}", [0.05, 0.2 + 0.02 * s]) for s in range(3)]
    student = [_run(tmp_path / f"s{s}", [0.18], ttf=0.7, steps=1_000_000) for s in range(3)]
    for s in range(3):
        assert ar.main(["--out", out, "--setting", "std", "--seed", str(s), "--commit", "abc",
                        "--run", f"teacher={teacher[s]}", "--run", f"student={student[s]}"]) == 0
    again = _run(tmp_path / "t0b", [0.26])  # seed 0's teacher rerun: its record replaced, not added
    assert ar.main(["--out", out, "--setting", "std", "--seed", "0", "--run", f"teacher={again}"]) == 0
    records = json.load(open(out))["records"]
    assert [(r["role"], r["seed"]) for r in records] == [("teacher", 0), ("teacher", 1), ("teacher", 2),
                                                         ("student", 0), ("student", 1), ("student", 2)]
    t0 = records[0]
    assert t0["rotation_rad_s"] == 0.26 and t0["curve"] == [[1000, 0.26, 0.9]] and t0["commit"] == "unknown"
    assert records[1]["curve"] == [[1000, 0.05, 0.9], [2000, 0.22, 0.9]] and records[1]["eval_episodes"] == 128.0
    lines = ar.report(records)
    assert "teacher  seeds 3: rate 0.240" in lines[0] and "goal met" in lines[0]  # (0.26 + 0.22 + 0.24) / 3
    assert "0.75x the teacher" in lines[1]  # 0.18 / 0.24
    capsys.readouterr()
    assert ar.main(["--out", out, "--run", "critic=" + teacher[0]]) == 2
    assert ar.main(["--out", out, "--run", "ppo=" + str(tmp_path / "missing")]) == 2
    assert "ROLE=LOGDIR" in capsys.readouterr().err


def test_png_draws_one_curve_per_record_with_evaluations(tmp_path):
    out = str(tmp_path / "allegro.json")
    for seed, rates in ((0, [0.1, 0.25]), (1, [0.05, 0.3])):
        assert ar.main(["--out", out, "--setting", "all", "--seed", str(seed),
                        "--run", f"teacher={_run(tmp_path / f't{seed}', rates)}"]) == 0
    png = str(tmp_path / "curves.png")
    with open(out) as f:
        assert ar.plot(json.load(f)["records"], png) == 2
    with open(png, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"


def test_final_evaluations_judge_the_role_and_give_the_neighbour_gap(tmp_path, capsys):
    """``final_eval_<step>.json`` (play's report) in a logdir: the record lists them by checkpoint, the gap of the
    last two (0.31 - 0.29 = 0.02), and the report's rate is the last large evaluation's, not the trainer's 0.5."""
    run = _run(tmp_path / "t0", [0.1, 0.5], ttf=0.6)
    for step, rate, ttf in ((4000, 0.31, 0.85), (3000, 0.29, 0.8), (2000, 0.1, 0.7)):
        with open(os.path.join(run, f"final_eval_{step}.json"), "w") as f:
            json.dump({"episodes": 768, "rotation_rate": rate, "rotation_rate_se": 0.01, "time_to_fall": ttf}, f)
    out = str(tmp_path / "allegro.json")
    assert ar.main(["--out", out, "--setting", "all", "--run", f"teacher={run}", "--report"]) == 0
    (rec,) = json.load(open(out))["records"]
    assert [e["checkpoint"] for e in rec["final_evals"]] == [2000, 3000, 4000]
    assert abs(rec["neighbour_gap_rad_s"] - 0.02) < 1e-9 and rec["rotation_rad_s"] == 0.5
    line = capsys.readouterr().out.splitlines()[-1]
    assert "rate 0.310 rad/s" in line and "768+ episodes" in line and "0.020 rad/s apart" in line
    assert "time to fall 0.85" in line and "goal met" in line


def test_a_run_without_its_summary_is_read_from_its_last_evaluation(tmp_path):
    """A run that ended without summary.json (the evaluation process killed by a signal, before 0c139d2): the last
    evaluation row gives the record, the last training row its steps and wall time, flagged ``no_summary``."""
    path = str(tmp_path / "t")
    os.makedirs(path)
    with open(os.path.join(path, "metrics.jsonl"), "w") as f:
        for step, rate in ((1000, 0.1), (2000, 0.25)):
            f.write(json.dumps({"step": step, "time/wall_s": step / 10, "loss/x": 1.0}) + "\n")
            f.write(json.dumps({"step": step, "eval/rotation_rate": rate, "eval/time_to_fall": 0.7,
                                "eval/rotate_reward": rate / 2, "eval/episodes": 128.0}) + "\n")
        f.write(json.dumps({"step": 2500, "time/wall_s": 321.0, "loss/x": 0.5}) + "\n")
    rec = ar.read_run(path)
    assert (rec["rotation_rad_s"], rec["time_to_fall"], rec["env_steps"], rec["wall_s"]) == (0.25, 0.7, 2500, 321.0)
    assert rec["interrupted"] is True and rec["no_summary"] is True and len(rec["curve"]) == 2
    os.remove(os.path.join(path, "metrics.jsonl"))
    open(os.path.join(path, "metrics.jsonl"), "w").close()
    try:
        ar.read_run(path)
    except ValueError as e:
        assert "no summary.json and no evaluation" in str(e)
    else:
        raise AssertionError("a run with neither a summary nor an evaluation gave a record")
