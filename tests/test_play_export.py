"""``python -m unilab_jax.export`` and ``python -m unilab_jax.play`` on the checkpoint of a tiny ppo_go1.py run,
as a user runs them (subprocesses), and that run's ``--video_every`` clips. The run is shared by the tests of
this file (about 20 s on the 2-core VM)."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from compile_options import fast_compile_env

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _run(args, timeout=600):
    # XLA compiles fast (tests/compile_options.py): the run makes four updates, the commands act a few steps.
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                          env=fast_compile_env())


@pytest.fixture(scope="module")
def go1_run(tmp_path_factory):
    logdir = str(tmp_path_factory.mktemp("ppo_go1") / "run")
    out = _run([os.path.join(ROOT, "experiments", "ppo_go1.py"), "--total_steps=1500", "--num_workers=1",
                "--envs_per_worker=16", "--eval_envs=2", "--task_config=episode_length=100", "--video_every=768",
                f"--logdir={logdir}"])
    assert out.returncode == 0, out.stderr[-3000:]
    return logdir


def _observations(run, n_steps=20):
    """Observations the policy meets on its task (4 envs, n_steps steps of the policy itself)."""
    task = run.make_task(4, seed=3)
    obs, _ = task.reset()
    seen = [obs]
    for _ in range(n_steps):
        obs = task.step(run.act(obs)).obs
        seen.append(obs)
    task.close()
    return np.concatenate(seen)


def test_exported_policy_acts_as_the_checkpoint(go1_run, tmp_path):
    import onnxruntime as ort

    from unilab_jax.apps import saved_run

    for fmt, out in (("onnx", tmp_path / "go1.onnx"), ("numpy", tmp_path / "go1_policy.py")):
        done = _run(["-m", "unilab_jax.export", "--logdir", go1_run, "--format", fmt, "--out", str(out)])
        assert done.returncode == 0, done.stderr[-3000:]
        assert json.loads(done.stdout)["algo"] == "ppo"
    run = saved_run.load(go1_run)
    obs = _observations(run)
    want = run.act(obs)
    session = ort.InferenceSession(str(tmp_path / "go1.onnx"), providers=["CPUExecutionProvider"])
    np.testing.assert_allclose(session.run(["action"], {"obs": obs})[0], want, rtol=1e-5, atol=1e-5)
    spec = importlib.util.spec_from_file_location("go1_policy", tmp_path / "go1_policy.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    np.testing.assert_allclose(module.Policy()(obs), want, rtol=1e-5, atol=1e-5)


def test_play_writes_a_video_of_the_policy(go1_run, tmp_path):
    import imageio.v3 as iio

    video = str(tmp_path / "go1.mp4")
    done = _run(["-m", "unilab_jax.play", "--logdir", go1_run, "--video", video, "--steps", "25", "--width", "160",
                 "--height", "120"])
    assert done.returncode == 0, done.stderr[-3000:]
    stats = json.loads(done.stdout)
    # One frame before each step of env 0's episode: 25 unless the robot fell before.
    assert 2 <= stats["frames"] == stats["episode_length"] <= 25
    assert stats["tracking_error"] > 0 and 0 <= stats["fall_rate"] <= 1  # the walking metric of a locomotion task
    frames = iio.imread(video)
    assert frames.shape == (stats["frames"], 120, 160, 3)
    assert frames.std() > 10  # a scene, not a blank image
    change = np.abs(frames[1:].astype(np.int16) - frames[:-1]).mean(axis=(1, 2, 3))
    assert (change > 0.5).sum() >= len(change) // 2, change  # the robot moves: most frames differ from the last


def test_play_refuses_a_missing_checkpoint(go1_run):
    done = _run(["-m", "unilab_jax.play", "--logdir", go1_run, "--checkpoint", "7"])
    assert done.returncode == 2 and "no checkpoint of step 7" in done.stderr and "steps: [" in done.stderr


def test_play_without_the_video_writer_exits_2_before_the_rollout(tmp_path):
    """Without imageio-ffmpeg, imageio would pick another plugin for ".mp4" (a TIFF writer that then fails on
    ``fps``, leaving an 8-byte file, as on the GPU machine): --video stops at once with the install hint, no file."""
    video = str(tmp_path / "go1.mp4")
    code = ("import sys; sys.modules['imageio_ffmpeg'] = None; from unilab_jax.apps.play import main; "
            f"sys.exit(main(['--logdir', {str(tmp_path / 'no_run')!r}, '--video', {video!r}]))")
    done = _run(["-c", code])
    assert done.returncode == 2 and "imageio-ffmpeg" in done.stderr and "unilab-jax[video]" in done.stderr
    assert "no checkpoint" not in done.stderr and not os.path.exists(video)  # refused before loading the run


def test_video_every_writes_clips_during_training(go1_run):
    import imageio.v3 as iio

    # Updates of 24 steps x 16 envs = 384 env steps: clips are due at 768 and 1536 (the last update).
    names = sorted(os.listdir(os.path.join(go1_run, "videos")))
    assert names == ["step_1536.mp4", "step_768.mp4"], names
    frames = iio.imread(os.path.join(go1_run, "videos", "step_768.mp4"))
    assert 2 <= len(frames) <= 100 and frames.shape[1:] == (240, 320, 3)  # one episode (length 100) at most
    events = [n for n in os.listdir(go1_run) if n.startswith("events.out.tfevents")]
    assert any(b"eval/clip" in open(os.path.join(go1_run, n), "rb").read() for n in events)


def test_video_every_must_not_be_negative():
    done = _run([os.path.join(ROOT, "experiments", "ppo_go1.py"), "--video_every=-5"])
    assert done.returncode == 2 and "--video_every must be >= 0" in done.stderr



def test_rollout_frames_api(go1_run, tmp_path):
    """The notebooks' API, in a fresh interpreter (the GL backend is chosen when mujoco is first imported)."""
    code = ("import json, sys\n"
            "from unilab_jax.apps import play\n"
            "frames, stats = play.rollout_frames(sys.argv[1], steps=5, width=64, height=48, "
            "task_overrides={'episode_length': 50})\n"
            "play.write_video(frames, sys.argv[2], stats['fps'])\n"
            "print(json.dumps({'shape': list(frames.shape), 'dtype': str(frames.dtype), **stats}))\n")
    done = _run(["-c", code, go1_run, str(tmp_path / "clip.mp4")])
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["shape"][1:] == [48, 64, 3] and out["dtype"] == "uint8" and 1 <= out["shape"][0] <= 5
    assert out["shape"][0] == out["episode_length"] and out["fps"] == 50 and out["algo"] == "ppo"
    assert os.path.getsize(tmp_path / "clip.mp4") > 0
