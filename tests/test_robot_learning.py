"""bench/robot_learning.py: evaluation reports of the Franka GPU jobs -> robot_learning.json records."""

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(ROOT, "bench", "robot_learning.py")


def _report(folder, name, success, fps=10):
    with open(os.path.join(folder, name), "w") as f:
        json.dump({"algo": "rlpd", "task": "robot_peg_insertion", "episodes": 40.0, "success_rate": success,
                   "fps": fps}, f)


def test_reports_become_records_and_a_rerun_replaces_its_own(tmp_path):
    runs, out = tmp_path / "runs", tmp_path / "robot_learning.json"
    runs.mkdir()
    _report(runs, "rlpd_peg_images_s0_eval40_3003.json", 0.5)
    _report(runs, "rlpd_peg_images_asym_s2_eval40_6000.json", 0.75)
    _report(runs, "rlpd_peg_s1_eval40_1200.json", 0.25, fps=20)
    (runs / "rlpd_peg_s1_summary.json").write_text("{}")  # not a report
    (runs / "rlpd_peg_s1_eval40_2400.json").write_text("")  # an evaluation stopped before its report: skipped
    cmd = [sys.executable, SCRIPT, str(runs), "--out", str(out), "--commit", "abc"]
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    assert "rlpd_peg_s1_eval40_2400.json: not a finished report" in done.stderr
    recs = {(r["job"], r["env_steps"]): r for r in json.loads(out.read_text())}
    assert set(recs) == {("rlpd_peg_images_s0", 3003), ("rlpd_peg_images_asym_s2", 6000), ("rlpd_peg_s1", 1200)}
    img = recs[("rlpd_peg_images_s0", 3003)]
    assert (img["observation"], img["asymmetric"], img["seed"], img["success"]) == ("images", False, 0, 0.5)
    assert abs(img["robot_minutes"] - 3003 / 600) < 1e-9 and img["episodes"] == 40
    assert recs[("rlpd_peg_images_asym_s2", 6000)]["asymmetric"] is True
    assert img["reward"] == "dense" and "machine" not in img  # every peg job trains with the shaped reward
    state = recs[("rlpd_peg_s1", 1200)]
    assert state["observation"] == "state" and state["robot_minutes"] == 1.0  # 1200 steps at 20 Hz
    _report(runs, "rlpd_peg_images_s0_eval40_3003.json", 0.9)
    subprocess.run(cmd, check=True, capture_output=True)
    again = json.loads(out.read_text())
    assert len(again) == 3 and [r["success"] for r in again if r["job"] == "rlpd_peg_images_s0"] == [0.9]


def test_a_folder_without_reports_exits_2(tmp_path):
    out = subprocess.run([sys.executable, SCRIPT, str(tmp_path), "--out", str(tmp_path / "o.json"), "--commit", "x"],
                         capture_output=True, text=True)
    assert out.returncode == 2 and "no <job>_eval40_<step>.json report" in out.stderr


def test_a_pair_jobs_reports_per_arm_are_records_of_their_arm(tmp_path):
    """The Franka + UR5e job evaluates each checkpoint on both arms: two records of one job and env step, and a
    record without ``arm`` (written before the field) counts as the Franka's when a rerun replaces it."""
    runs, out = tmp_path / "runs", tmp_path / "robot_learning.json"
    runs.mkdir()
    out.write_text(json.dumps([{"job": "rlpd_pick_images_pair_s0", "env_steps": 3000, "success": 0.1}]))
    _report(runs, "rlpd_pick_images_pair_s0_eval40_3000.json", 0.5)
    _report(runs, "rlpd_pick_images_pair_s0_ur5e_eval40_3000.json", 0.25)
    subprocess.run([sys.executable, SCRIPT, str(runs), "--out", str(out), "--commit", "abc"], check=True,
                   capture_output=True)
    recs = json.loads(out.read_text())
    assert sorted((r["arm"], r["success"], r["seed"]) for r in recs) == [("franka", 0.5, 0), ("ur5e", 0.25, 0)]
    assert {r["reward"] for r in recs} == {"success"} and not any(r["interventions"] for r in recs)


def test_the_shaped_and_corrected_pick_jobs_say_so(tmp_path):
    """``reward``: dense for peg insertion (every peg job trains shaped) and the ``_dense`` / ``_gate`` pick jobs;
    ``interventions`` for the ``_gate`` jobs only."""
    runs, out = tmp_path / "runs", tmp_path / "robot_learning.json"
    runs.mkdir()
    jobs = ("rlpd_pick_images_dense_s1", "rlpd_pick_images_gate_pair_s0", "rlpdflow_peg_images_s2", "rlpd_pick_s0",
            "sacflow_pick_s1")
    for job in jobs:
        _report(runs, f"{job}_eval40_600.json", 0.5)
    subprocess.run([sys.executable, SCRIPT, str(runs), "--out", str(out), "--commit", "abc", "--machine", "2x H200"],
                   check=True, capture_output=True)
    written = json.loads(out.read_text())
    recs = {r["job"]: (r["reward"], r["interventions"]) for r in written}
    assert {r["machine"] for r in written} == {"2x H200"}
    assert [recs[j] for j in jobs] == [("dense", False), ("dense", True), ("dense", False), ("success", False),
                                       ("success", False)]
