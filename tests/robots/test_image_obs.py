"""Image observations of the robot tasks: frame stacks by hand, camera checks, and the uint8 image path from the
robot to the learner's batch, byte for byte (worker processes, shared-memory replay, disk store, prior data,
device mirror)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
import robot_image_algo
from pattern_robot import PROPRIO, frame, serving

import tasks
from unilab_jax import xp as shim
from unilab_jax.apps import record
from unilab_jax.fields import IMAGE_FIELDS, REPLAY_FIELDS, prior_fields, replay_fields
from unilab_jax.robots import inventory
from unilab_jax.robots.client import RobotClient
from unilab_jax.runtime.buffers import transition_layout
from unilab_jax.runtime.pool import WorkerPool
from unilab_jax.runtime.prior import load_prior
from unilab_jax.runtime.replay_store import ReplayStore
from unilab_jax.training.evaluation import deterministic_policy, run_episodes
from unilab_jax.training.sources import ReplaySource

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CAMERAS, SIZE, STACK = ("wrist", "front"), 16, 3  # the task's camera order differs from the server's (front, wrist)
IMAGES = {"cameras": CAMERAS, "image_size": SIZE, "frame_stack": STACK}
PER_FRAME = 3 * len(CAMERAS)
ZERO = np.zeros((1, 7), np.float32)


def frames_of(obs: np.ndarray) -> np.ndarray:
    """[S, S, 6]: the frame the pattern robot sent with an observation (the task's camera order)."""
    return np.concatenate([frame(obs[:PROPRIO], c, SIZE) for c in CAMERAS], axis=-1)


def test_frame_stacks_by_hand():
    """One robot, episodes of 4 steps: the stacks are [f0 f0 f0], [f0 f0 f1], [f0 f1 f2], ... (oldest first),
    ``image`` / ``next_image`` are the stacks of obs / next_obs, and a new episode repeats its first frame."""
    with serving(1) as addresses:
        task = tasks.make("robot_peg_insertion", 1, 0, {"robots": tuple(addresses), **IMAGES, "episode_length": 4})
        try:
            assert task.spec.image_shape == (SIZE, SIZE, 3 * 2 * 3)
            assert ("image", (SIZE, SIZE, 18), "uint8") in task.spec.transition_fields
            obs, _ = task.reset()
            f = [frames_of(obs[0])]
            stack = lambda *k: np.concatenate([f[i] for i in k], axis=-1)  # noqa: E731
            np.testing.assert_array_equal(task.images()[0], stack(0, 0, 0))
            want = [((0, 0, 0), (0, 0, 1)), ((0, 0, 1), (0, 1, 2)), ((0, 1, 2), (1, 2, 3)), ((1, 2, 3), (2, 3, 4))]
            for t, (image, next_image) in enumerate(want):
                out = task.step(ZERO)
                f.append(frames_of(out.next_obs[0]))
                assert out.extras["image"].dtype == np.uint8 and out.extras["image"].shape == (1, SIZE, SIZE, 18)
                np.testing.assert_array_equal(out.extras["image"][0], stack(*image))
                np.testing.assert_array_equal(out.extras["next_image"][0], stack(*next_image))
                assert bool(out.truncated[0]) == (t == 3)
                if t < 3:
                    np.testing.assert_array_equal(task.images()[0], stack(*next_image))
            f.append(frames_of(out.obs[0]))  # f[5]: the first frame of the next episode
            assert not np.array_equal(f[5], f[4])
            np.testing.assert_array_equal(task.images()[0], stack(5, 5, 5))
            out = task.step(ZERO)
            f.append(frames_of(out.next_obs[0]))
            np.testing.assert_array_equal(out.extras["next_image"][0], stack(5, 5, 6))
            handed, kept = out.extras["next_image"], out.extras["next_image"].copy()
            task.reset()  # restarts every stack, into new arrays: what was handed out stays as it was
            np.testing.assert_array_equal(handed, kept)
            # evaluation / play act on the task's current images (the algorithm refuses to act without them)
            _, stats = run_episodes(task, deterministic_policy(robot_image_algo, {}, task), max_steps=3)
            assert stats["episode_length"] == 3
        finally:
            task.close()


def test_camera_and_config_mismatches_are_refused():
    with serving(1, cameras=("front",), size=SIZE) as addresses:
        for bad, message in [({"cameras": ("wrist",)}, r"renders \['front'\]"),
                             ({"image_size": 32}, r"at \(32, 32, 3\), the robot renders \['front'\] at \(16, 16, 3\)")]:
            with pytest.raises(ValueError, match=message):
                tasks.make("robot_peg_insertion", 1, 0, {"robots": tuple(addresses), **IMAGES, **bad})
    for bad in ({"cameras": ("top",)}, {"cameras": ("front", "front")}, {"image_size": 8}, {"frame_stack": 0}):
        with pytest.raises(ValueError):
            tasks.make("robot_peg_insertion", 1, 0, {**IMAGES, **bad})


def test_rendered_images_through_a_robot_server(serve, gl_backend):
    """A real server rendering its front camera (MuJoCo on the GL backend found here) into a 2-frame stack."""
    server = serve("--robot=franka", "--task=peg_insertion", "--speed=50", "--reset_s=0", "--cameras=front",
                   "--image_size=32", env={"MUJOCO_GL": gl_backend})
    task = tasks.make("robot_peg_insertion", 1, 0, {"robots": (server.address,), "cameras": ("front",),
                                                      "image_size": 32, "frame_stack": 2})
    try:
        task.reset()
        first = task.images()[0]
        assert first.shape == (32, 32, 6) and first.dtype == np.uint8 and first.std() > 5  # a scene, not a blank
        np.testing.assert_array_equal(first[..., :3], first[..., 3:])
        out = task.step(np.array([[0, 0, -1, 0, 0, 0, 1]], np.float32))
        np.testing.assert_array_equal(out.extras["image"][0], first)
        np.testing.assert_array_equal(out.extras["next_image"][0, ..., :3], first[..., 3:])
    finally:
        task.close()
    with pytest.raises(ValueError, match="--image_size=64"):
        tasks.make("robot_peg_insertion", 1, 0, {"robots": (server.address,), "cameras": ("front",)})


def _check_rows(batch: dict, what: str) -> int:
    """Every row's images are the robot's frames of its obs / next_obs; returns the rows that start an episode."""
    image, next_image = np.asarray(batch["image"]), np.asarray(batch["next_image"])
    obs, next_obs = np.asarray(batch["obs"]), np.asarray(batch["next_obs"])
    assert image.dtype == next_image.dtype == np.uint8, what
    image, next_image = image.reshape(-1, SIZE, SIZE, 18), next_image.reshape(-1, SIZE, SIZE, 18)
    obs, next_obs = obs.reshape(len(image), -1), next_obs.reshape(len(image), -1)
    starts = np.asarray(batch["critic_obs"]).reshape(len(image), -1)[:, -1] == 0
    for i in range(len(image)):
        assert image[i, ..., -PER_FRAME:].tobytes() == frames_of(obs[i]).tobytes(), (what, i)
        assert next_image[i, ..., -PER_FRAME:].tobytes() == frames_of(next_obs[i]).tobytes(), (what, i)
        assert next_image[i, ..., :-PER_FRAME].tobytes() == image[i, ..., PER_FRAME:].tobytes(), (what, i)
        if starts[i]:
            assert image[i].tobytes() == np.tile(image[i, ..., -PER_FRAME:], (1, 1, STACK)).tobytes(), (what, i)
    return int(starts.sum())


def test_images_arrive_byte_exact_in_learner_batches(tmp_path):
    """Two pattern robots behind servers, two worker processes: demonstrations recorded with images (the prior
    data), replay in shared memory, a disk store and the device mirror. Every row of the learner's batches holds
    the frames the robot sent with its obs / next_obs (uint8 all the way), and the policy acted on that image."""
    with serving(2) as addresses:
        overrides = {"robots": tuple(addresses), **IMAGES, "episode_length": 12}
        demos = str(tmp_path / "demos")
        summary = record.record(list(addresses), "robot_peg_insertion", 2, demos, overrides=overrides)
        assert summary["episodes"] == 2
        pool = WorkerPool("robot_peg_insertion", overrides, num_workers=2, envs_per_worker=1,
                          algo_module="robot_image_algo", weight_template={"w": np.zeros(1, np.float32)},
                          replay_capacity=500)
        with pool:
            assert pool.buffer.fields["image"] == ((SIZE, SIZE, 18), np.dtype(np.uint8))
            pool.start()
            pool.publish({"w": np.zeros(1, np.float32)}, 1)
            deadline = time.monotonic() + 120
            while pool.env_steps() < 300:
                assert time.monotonic() < deadline, "the workers did not produce 300 steps"
                time.sleep(0.05)
            raw = pool.sample(256, np.random.default_rng(0), serial_steps=0)
            for i in range(256):  # the worker's policy acted on exactly the image stored with the row
                assert raw["seen"][i].tobytes() == robot_image_algo.digest(raw["image"][i]).tobytes()
            assert _check_rows(raw, "ring") > 0

            layout = transition_layout(pool.spec, robot_image_algo.extras(7))
            prior = load_prior(demos, {k: layout[k] for k in prior_fields(pool.spec)})
            assert set(prior) == set(REPLAY_FIELDS + IMAGE_FIELDS) and prior["image"].dtype == np.uint8
            _check_rows(prior, "prior")
            prior_obs = {o.tobytes() for o in prior["obs"]}
            store = ReplayStore(str(tmp_path / "replay"), {k: layout[k] for k in replay_fields(pool.spec)})
            cfg = SimpleNamespace(batch_size=64, updates_per_call=2, learning_starts=64, utd=1e9, publish_every=2,
                                  prior_fraction=0.5)
            from unilab_jax.training.device_replay import DeviceReplay

            sources = {"host": (shim.get("numpy"), None, None), "disk": (shim.get("numpy"), store, None),
                       "device": (shim.get("jax"), None, DeviceReplay(pool.buffer, replay_fields(pool.spec)))}
            for what, (xp, st, mirror) in sources.items():
                source = ReplaySource(pool, xp, cfg, {"env_steps": 0, "updates": 0}, 0, st, 0.5, None, mirror,
                                       total_steps=10**6, prior=prior)
                out, _ = source.produce(threading.Event())
                source.stop()
                if what == "device":  # the mirror's batch is finished by the thread that runs the update
                    out = out()
                assert out["image"].shape == (2, 64, SIZE, SIZE, 18) and str(out["image"].dtype) == "uint8", what
                assert set(replay_fields(pool.spec)) - {"source"} <= set(out)
                _check_rows(out, what)
                from_prior = sum(o.tobytes() in prior_obs for o in np.asarray(out["obs"]).reshape(128, -1))
                assert from_prior >= 64, (what, from_prior)  # the prior half (and online rows never repeat them)
            assert store.size > 0 and store.fields["image"][1] == np.dtype(np.uint8)
            _check_rows(store.read(store.first_row, store.committed), "store")
            store.close()


def test_record_demonstrations_with_images(tmp_path, capsys):
    """``python -m unilab_jax.robots.record --cameras=...``: a sim: server rendering the camera, demonstrations with
    uint8 frame stacks whose episodes chain (each row's next_image is the next row's image)."""
    out = str(tmp_path / "demos")
    rc = record.main(["--robots=sim:franka_emika_panda", "--task=robot_peg_insertion", "--episodes=1", f"--out={out}",
                      "--speed=50", "--cameras=front", "--image_size=32", "--frame_stack=2"])
    assert rc == 0, capsys.readouterr().err
    with ReplayStore(out) as store:
        rows = store.read(store.first_row, store.committed)
    assert rows["image"].shape[1:] == (32, 32, 6) and rows["image"].dtype == np.uint8
    np.testing.assert_array_equal(rows["image"][1:], rows["next_image"][:-1])
    np.testing.assert_array_equal(rows["image"][0, ..., :3], rows["image"][0, ..., 3:])  # the first frame, twice
    assert rows["image"].std() > 5
    for bad in ("--frame_stack=0", "--cameras=top", "--image_size=8"):
        assert record.main(["--episodes=1", f"--out={tmp_path / 'x'}", "--cameras=front", bad]) == 2
        assert "error:" in capsys.readouterr().err


def test_a_runs_sim_servers_draw_the_arm_with_its_camera_geometry():
    """``Inventory(camera_geometry=...)`` (a robot experiment's ``--task_config=camera_geometry``) reaches the sim:
    servers it starts: after the same seeded reset, the front frame with the arm's collision shapes differs from the
    one with its visual meshes (which arm geometry the server draws: tests/robots/test_robot_sim.py)."""
    frames = {}
    for geometry in ("collision", "visual"):
        with inventory.Inventory(inventory.parse("sim:franka_emika_panda"), "peg_insertion", 50.0, cameras=("front",),
                                 image_size=16, camera_geometry=geometry) as inv:
            client = RobotClient(inv.addresses[0], timeout_s=10.0)
            client.connect()
            try:
                frames[geometry] = client.reset(seed=1)["front"]
            finally:
                client.close()
    assert frames["collision"].shape == frames["visual"].shape == (16, 16, 3)
    assert frames["collision"].std() > 5 and not np.array_equal(frames["collision"], frames["visual"])


def test_experiment_refuses_a_server_without_the_cameras(tmp_path, serve):
    """rlpd_franka_peg.py (images by default) on a running server that renders no camera: exit 2 before any
    demonstration or worker, naming the server flags it needs."""
    server = serve("--robot=franka", "--task=peg_insertion", "--speed=20", "--reset_s=0", "--cameras=none")
    out = subprocess.run([sys.executable, os.path.join(ROOT, "experiments", "rlpd_franka_peg.py"),
                          f"--robots={server.address}", f"--logdir={tmp_path / 'run'}"], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "serve it with --cameras=front,wrist --image_size=32" in out.stderr and "Traceback" not in out.stderr
    assert not (tmp_path / "run" / "demos").exists()


@pytest.mark.parametrize("critic_state", [False, True])
def test_the_policy_observation_holds_no_privileged_state(critic_state):
    """The image runs' task options (``robot_cli.IMAGE_TASK`` less the cameras: in-process robots render in this
    process only with a GL backend chosen before mujoco's import): two robots of one seed, the hole of one moved by
    5 cm, the same actions. The privileged state differs, the policy's observation (proprioception and kind) stays
    byte for byte the same, so every policy acts the same on it; the critic's differs only with ``critic_state``
    (the asymmetric actor-critic of ``--asymmetric``)."""
    import mujoco

    from unilab_jax.apps.robot_cli import IMAGE_TASK, ROBOT_TASK

    overrides = {**ROBOT_TASK, **IMAGE_TASK, "cameras": (), "critic_state": critic_state, "episode_length": 5}
    pair = [tasks.make("robot_peg_insertion", 1, 7, overrides) for _ in range(2)]
    try:
        first = [t.reset() for t in pair]
        robot = pair[1].robots[0]
        robot.data.mocap_pos[robot.model.body("block").mocapid[0], :2] += 0.05
        mujoco.mj_forward(robot.model, robot.data)
        action = np.array([[0.3, -0.2, 0.1, 0, 0, 0, 1]], np.float32)
        outs = [t.step(action) for t in pair]
        hole = [t.observation(0)["privileged"][11:14] for t in pair]
        np.testing.assert_allclose(hole[1][:2] - hole[0][:2], 0.05, atol=1e-6)
        assert pair[0].spec.obs_dim == 13 + 2  # proprioception and the kind one-hot, nothing else
        assert first[0][0].tobytes() == first[1][0].tobytes()
        assert outs[0].next_obs.tobytes() == outs[1].next_obs.tobytes()
        assert outs[0].obs.tobytes() == outs[1].obs.tobytes()
        same_critic = outs[0].next_critic_obs.tobytes() == outs[1].next_critic_obs.tobytes()
        assert same_critic != critic_state
        assert pair[0].spec.critic_obs_dim == 15 + critic_state * pair[0].robot_spec.privileged_dim + 1
    finally:
        for t in pair:
            t.close()
