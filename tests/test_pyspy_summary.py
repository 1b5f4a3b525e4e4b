"""bench/pyspy_summary.py: a py-spy profile (collapsed stacks with thread frames) -> per-thread shares, sample states,
self and inclusive frames, and CPU % from two /proc task snapshots."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(ROOT, "bench", "pyspy_summary.py")
_spec = importlib.util.spec_from_file_location("pyspy_summary", SCRIPT)
ps = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(ps)

BOOT = ["0x7f00000028ec (libc.so.6)", "Thread._bootstrap (threading.py:1002)", "Thread.run (threading.py:982)",
        "_loop (unilab_jax/training/threads.py:95)"]
NP = "_multiarray_umath.cpython-312-x86_64-linux-gnu.so"
# A learner thread in 10 samples: 4 dispatching (3 in XLA's execute, 1 in Python), 3 waiting for the GIL, 3 blocked
# on its job queue. A loop thread: 5 in the driver, 5 copying in numpy. py-spy's raw format, as written by --threads.
STACKS = [
    ("thread (101): learner", *BOOT, "_dispatch (trainer.py:500)", "PjitFunction::Call (libjax_common.so)",
     "xla::PjRtStreamExecutorLoadedExecutable::Execute (libjax_common.so)", 3),
    ("thread (101): learner", *BOOT, "_dispatch (trainer.py:501)", 1),
    ("thread (101): learner", *BOOT, "_dispatch (trainer.py:502)", f"array_copy ({NP})",
     "pthread_cond_timedwait (libc.so.6)", "0x7f0000003f16 (libc.so.6)", 3),
    ("thread (101): learner", *BOOT[:3], "_loop (unilab_jax/training/threads.py:96)", "get (queue.py:171)",
     "PyThread_acquire_lock_timed (libpython3.12.so.1.0)", "0x7f0000004193 (libc.so.6)", 3),
    ("thread (7): MainThread", "<module> (run.py:1)", "_fetch (trainer.py:560)", "0x7f00000a1000 (libcuda.so.1)", 5),
    ("thread (7): MainThread", "<module> (run.py:1)", "_fetch (trainer.py:561)",
     f"_contig_to_contig (/x/numpy/_core/{NP})", 5),
]
RAW = "".join(";".join(s[:-1]) + f" {s[-1]}\n" for s in STACKS)


def _summary(tmp_path, **kw):
    raw = tmp_path / "p.raw"
    raw.write_text(RAW)
    return ps.summarize(ps.parse_raw(raw.read_text().splitlines()), **kw)


def test_threads_states_and_frames(tmp_path):
    s = _summary(tmp_path)
    assert s["samples"] == 20
    threads = {t["name"]: t for t in s["threads"]}
    learner, main = threads["learner"], threads["MainThread"]
    assert (learner["tid"], learner["samples"], learner["share_of_process"]) == ("101", 10, 0.5)
    assert learner["states"] == {"native:libjax_common.so": 0.3, "gil_wait": 0.3, "blocked": 0.3, "python": 0.1}
    assert main["states"] == {"cuda_driver": 0.5, "native:_multiarray_umath.so": 0.5}
    # self: the innermost named frame (unnamed addresses skipped, line numbers and .cpython-* dropped)
    assert dict(learner["self"]) == {"xla::PjRtStreamExecutorLoadedExecutable::Execute (libjax_common.so)": 0.3,
                                     "pthread_cond_timedwait (libc.so.6)": 0.3,
                                     "PyThread_acquire_lock_timed (libpython3.12.so.1.0)": 0.3,
                                     "_dispatch (trainer.py)": 0.1}
    assert dict(main["self"]) == {"? (libcuda.so.1)": 0.5, "_contig_to_contig (_multiarray_umath.so)": 0.5}
    # inclusive: the frames on every sample of the thread (its entry points) are left out
    incl = dict(learner["inclusive"])
    assert incl["_dispatch (trainer.py)"] == 0.7 and incl["PjitFunction::Call (libjax_common.so)"] == 0.3
    assert "_loop (unilab_jax/training/threads.py)" not in incl and "Thread.run (threading.py)" not in incl
    assert dict(learner["python"]) == {"_dispatch (trainer.py)": 0.7, "get (queue.py)": 0.3}
    assert dict(main["python"]) == {}  # both Python frames are on every sample, the rest is native


def test_python_only_stacks_class_the_standard_library_waits():
    run = "thread (0x7f01): prefetch;Thread.run (threading.py:982)"
    stacks = ps.parse_raw([f"{run};Condition.wait (threading.py:327) 4", f"{run};produce (sources.py:250) 1"])
    (t,) = ps.summarize(stacks)["threads"]
    assert (t["tid"], t["states"]) == ("0x7f01", {"blocked": 0.8, "python": 0.2})


def test_cli_with_task_snapshots(tmp_path):
    hz = os.sysconf("SC_CLK_TCK")
    raw = tmp_path / "p.raw"
    raw.write_text(RAW)
    # stat lines: utime and stime are fields 14 and 15, the last core field 39; thread 9 (native) is not in the profile
    def stat(tid, comm, ticks, core):
        return f"{tid} ({comm}) S 1 " + " ".join(["0"] * 9) + f" {ticks} 0 " + " ".join(["0"] * 23) + f" {core} 0"
    (tmp_path / "s0").write_text("100.0\n" + "\n".join([stat(101, "python3", 0, 0), stat(7, "python3", 0, 0),
                                                        stat(9, "tf_XLA Eigen)", hz, 2)]) + "\n")
    (tmp_path / "s1").write_text("102.0\n" + "\n".join([stat(101, "python3", hz, 1), stat(7, "python3", hz // 2, 0),
                                                        stat(9, "tf_XLA Eigen)", 3 * hz, 2)]) + "\n")
    out = tmp_path / "s.json"
    res = subprocess.run([sys.executable, SCRIPT, str(raw), "--taskstat", str(tmp_path / "s0"), str(tmp_path / "s1"),
                          "--out", str(out)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    s = json.loads(out.read_text())
    assert s["process_cpu_pct"] == 175.0
    assert [(r["name"], r["cpu_pct"], r["core"]) for r in s["threads_cpu"]] == [
        ("tf_XLA Eigen)", 100.0, 2), ("learner", 50.0, 1), ("MainThread", 25.0, 0)]
    assert [(t["name"], t["cpu_pct"]) for t in s["threads"]] == [("learner", 50.0), ("MainThread", 25.0)]
    assert "tf_XLA Eigen) (9) 100.0" in res.stdout  # the native thread py-spy does not sample
    bad = subprocess.run([sys.executable, SCRIPT, str(tmp_path / "missing.raw")], capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1
