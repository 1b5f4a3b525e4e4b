"""Deterministic episodes of a policy, and the trainer's evaluations and clips built on them.

``run_episodes`` steps a task's envs through one episode each with a deterministic ``act`` (the trainer's
evaluations, ``python -m unilab_jax.play``); ``SceneRenderer`` renders one env through the task's
``render_scene`` hook; ``evaluate_policy`` is the trainer's evaluation (a fresh task, one episode per env, the
walking criterion on locomotion tasks); ``AsyncEvaluator`` and ``ClipRecorder`` run evaluations and
``--video_every`` clips in background threads on weight snapshots, so training is never held up. With a learner on
an accelerator the evaluations' episodes run in a process of their own (``EvaluationProcess``): stepped in a thread
of the learner's process, their Python held the interpreter lock the learner's thread needs to dispatch its
updates (FastSAC Go1 on the H100 machine: 28.3 learner calls/s with evaluations in a thread, 34.5 without any).
Importing this module chooses no ``MUJOCO_GL``: the processes that render choose it before mujoco is imported
(``python -m unilab_jax.play`` at its start, the experiments' ``--video_every`` check; ``robots.gl.prefer_headless``).
"""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
from collections.abc import Callable
from concurrent.futures.process import BrokenProcessPool
from typing import Any

import numpy as np

from unilab_jax.metrics import evaluation_line
from unilab_jax.runtime.ring import StopRequested

log = logging.getLogger(__name__)


def _moves_freely(model: Any, body: int) -> bool:
    """A floating base (free joint) or a planar root (two or more slide joints, e.g. Gymnasium's HalfCheetah
    and Hopper): the camera follows it. One slider (cart-pole's rail) keeps the whole model in view."""
    import mujoco

    types = model.jnt_type[model.jnt_bodyid == body]
    return bool((types == mujoco.mjtJoint.mjJNT_FREE).any() or (types == mujoco.mjtJoint.mjJNT_SLIDE).sum() >= 2)


class SceneRenderer:
    """Renders env ``env`` of a task through its ``render_scene`` hook, with a camera that follows a floating
    base (locomotion) or frames the whole model (fixed-base tasks such as cart-pole)."""

    def __init__(self, task: Any, width: int = 320, height: int = 240, env: int = 0):
        import mujoco

        model, _ = task.render_scene(env)
        self._task, self._env = task, env
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, height)
        try:
            self._renderer = mujoco.Renderer(model, height, width)
        except Exception as e:
            raise RuntimeError(
                f"cannot create an offscreen renderer ({type(e).__name__}: {e}); MUJOCO_GL="
                f"{os.environ.get('MUJOCO_GL', '')!r}. Headless Linux needs MUJOCO_GL=egl set before mujoco is "
                "imported and the EGL packages (apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0)"
            ) from e
        # Shadows and reflections off: with Mesa's software rasteriser they cost ~7x the rest of a frame
        # (measured at 320x240 on the 2-core VM: 150 ms vs 20 ms of CPU per Go1 frame).
        for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION):
            self._renderer.scene.flags[flag] = 0
        # Training models keep only collision geoms (tasks strip visual meshes), which sit in group 3: show it.
        self.option = mujoco.MjvOption()
        self.option.geomgroup[:4] = 1
        # Where the stripped meshes were a body's only geoms (G1), its equivalent inertia box stands in.
        bare = np.setdiff1d(np.flatnonzero(model.body_mass > 0), model.geom_bodyid)
        self.option.flags[mujoco.mjtVisFlag.mjVIS_INERTIA] = bare.size > 0
        if model.nlight == 0:  # models without lights (cart-pole) are lit by a brighter headlight
            model.vis.headlight.ambient[:] = np.maximum(model.vis.headlight.ambient, 0.4)
            model.vis.headlight.diffuse[:] = np.maximum(model.vis.headlight.diffuse, 0.8)
        self.camera = mujoco.MjvCamera()
        if model.njnt and _moves_freely(model, int(model.jnt_bodyid[0])):
            self.camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
            self.camera.trackbodyid = root = int(model.jnt_bodyid[0])
            # The scene's size, at most 3x the robot's: a rough task's terrain makes ``model.stat.extent`` ~100 m.
            _, data = task.render_scene(env)
            own = np.flatnonzero(model.body_rootid[model.geom_bodyid] == root)
            reach = np.linalg.norm(data.geom_xpos[own] - data.xpos[root], axis=1) + model.geom_rbound[own]
            self.camera.distance = max(1.5, 2.0 * min(model.stat.extent, 3.0 * float(reach.max(initial=0.0))))
            self.camera.elevation, self.camera.azimuth = -20.0, 135.0
        else:
            self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
            self.camera.lookat[:] = model.stat.center
            self.camera.distance, self.camera.elevation, self.camera.azimuth = 1.1 * model.stat.extent, -10.0, 90.0

    def frame(self) -> np.ndarray:
        """[H, W, 3] uint8 of the env's current state."""
        _, data = self._task.render_scene(self._env)
        self._renderer.update_scene(data, self.camera, self.option)
        return self._renderer.render().copy()

    def close(self) -> None:
        self._renderer.close()


def deterministic_policy(module: Any, weights: dict, task: Any) -> Callable[[np.ndarray], np.ndarray]:
    """``obs -> action`` of the deterministic worker policy ``module.act(weights, obs, zeros, True)`` on ``task``'s
    envs; on a task with images (``spec.image_shape``) it also acts on the task's current ``images()``."""
    zeros = np.zeros((task.num_envs, task.spec.action_dim), np.float32)
    if getattr(task.spec, "image_shape", ()):
        return lambda obs: module.act(weights, obs, zeros, True, image=task.images())[0]
    return lambda obs: module.act(weights, obs, zeros, True)[0]


MAX_EVAL_RESTARTS = 3  # interrupted evaluations (robot tasks) started over before the interruption is raised


def run_episodes(task: Any, act: Callable[[np.ndarray], np.ndarray], *, max_steps: int | None = None,
                 render: tuple[int, int] | None = None,
                 stop: threading.Event | None = None) -> tuple[np.ndarray, dict[str, float]]:
    """Steps every env of ``task`` with the deterministic ``act(obs) -> action`` through its first episode (at
    most ``max_steps`` control steps), rendering env 0 before every step of its episode when ``render`` is
    ``(width, height)``. Returns (frames [T, H, W, 3] uint8, T = env 0's steps, empty without ``render``;
    stats: ``return``/``return_std``/``episode_length`` over the ``episodes`` (envs), ``success_rate`` on tasks
    whose termination is success, ``protective_stops`` (episodes a robot ended by stopping on a safety limit: they
    failed, the others went on) and ``restarts`` (episodes started over after a robot was lost) where there were
    any, the ``LOGGED`` entries of the task's own metric where it has one
    (``task.eval_tracker()``, e.g. ``g1_track``'s clip completion), else the walking metric on locomotion tasks).
    The trainer's evaluations run it too; ``stop`` set before the episodes end raises :class:`StopRequested`."""
    from tasks.base import StepInterrupted
    from tasks.walking_metric import WalkingTracker, is_locomotion

    m = task.num_envs
    limit = task.spec.episode_length if max_steps is None else min(int(max_steps), task.spec.episode_length)
    if limit < 1:
        raise ValueError(f"steps must be positive, got {max_steps}")
    tracker = (task.eval_tracker() if hasattr(task, "eval_tracker")
               else WalkingTracker(task) if is_locomotion(task) else None)
    step = tracker.step if tracker is not None else task.step
    renderer = SceneRenderer(task, *render) if render is not None else None
    restarts = protective_stops = 0
    ends_on_stop = getattr(task, "stop_ends_episode", None)
    if ends_on_stop is not None:  # a robot task: while evaluating, a protective stop ends that episode, failed
        task.stop_ends_episode = True
    try:
        obs, _ = task.reset()
        ret, length = np.zeros(m), np.zeros(m, dtype=np.int64)
        alive, terminated = np.ones(m, dtype=bool), np.zeros(m, dtype=bool)
        frames = []
        t = 0
        while t < limit:
            t += 1
            if stop is not None and stop.is_set():
                raise StopRequested("evaluation stopped")
            if renderer is not None and alive[0]:
                frames.append(renderer.frame())
            try:
                out = step(np.asarray(act(obs), np.float32))
            except StepInterrupted as e:
                # A robot task lost a robot: every env was reset, so the episodes start over (a task with its own
                # tracker keeps state across steps: its evaluation cannot restart).
                restarts += 1
                if tracker is not None or restarts > MAX_EVAL_RESTARTS:
                    raise
                obs, t, protective_stops = e.obs, 0, 0
                ret[:], length[:], alive[:], terminated[:], frames = 0.0, 0, True, False, []
                continue
            if out.extras is not None and "protective_stop" in out.extras:
                protective_stops += int(np.sum(alive & out.extras["protective_stop"]))
            ret += np.where(alive, out.reward, 0.0)
            length += alive
            terminated |= alive & out.terminated
            alive &= ~(out.terminated | out.truncated)
            obs = out.obs
            if not alive.any():
                break
    finally:
        if renderer is not None:
            renderer.close()
        if ends_on_stop is not None:
            task.stop_ends_episode = ends_on_stop
    stats = {"return": float(ret.mean()), "return_std": float(ret.std()), "episode_length": float(length.mean()),
             "episodes": float(m)}
    if restarts:
        stats["restarts"] = float(restarts)
    if protective_stops:
        stats["protective_stops"] = float(protective_stops)
    if task.spec.success_on_termination:
        stats["success_rate"] = float(terminated.mean())
    if tracker is not None:
        metric = tracker.result()
        stats.update({k: metric[k] for k in tracker.LOGGED})
    shape = (0, render[1], render[0], 3) if render is not None else (0, 0, 0, 3)
    return (np.stack(frames) if frames else np.zeros(shape, np.uint8)), stats


def evaluate_policy(algo: Any, weights: dict, task: str, overrides: dict[str, Any], num_envs: int, seed: int,
                    stop: Any = None) -> dict[str, float]:
    """The trainer's evaluation: the deterministic policy of ``algo`` (its module, or the module's name) with
    ``weights`` for one full episode in each of ``num_envs`` envs of a fresh ``task`` (or as many as it could build,
    e.g. the robots that answer; seed ``10_000 + seed``), no operator interventions; ``eval/*`` scalars, with
    ``eval/walking`` on locomotion tasks. ``stop`` (anything with ``is_set()``) set before the episodes end raises
    :class:`StopRequested`."""
    import importlib

    import tasks
    from unilab_jax.metrics import WALKING

    module = importlib.import_module(algo) if isinstance(algo, str) else algo
    env = tasks.make(task, num_envs=num_envs, seed=10_000 + seed, overrides=overrides)
    if hasattr(env, "set_operator"):  # the policy alone: no operator interventions while evaluating
        env.set_operator("off")
    try:
        _, stats = run_episodes(env, deterministic_policy(module, weights, env), stop=stop)
    finally:
        env.close()
    result = {f"eval/{k}": v for k, v in stats.items()}
    if "tracking_error" in stats:  # locomotion: the walking criterion on the same episodes
        result["eval/walking"] = float(WALKING.met(stats))  # 1: it walks
    return result


_CHILD_STOP: Any = None  # in an EvaluationProcess's child: the parent's stop event


def _child_init(stop: Any) -> None:
    global _CHILD_STOP
    # Ctrl-C and `timeout`/`kill -TERM -<pgid>` reach the whole process group: the trainer handles them and ends
    # this child's episodes through ``stop`` (as it stops the rollout workers, runtime.worker.worker_main); a
    # child killed here broke the trainer's pool and ended the run without its summary.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _CHILD_STOP = stop


def _child_evaluate(job: dict[str, Any]) -> dict[str, float]:
    return evaluate_policy(**job, stop=_CHILD_STOP)


def _child_ready() -> bool:
    return True


class EvaluationProcess:
    """One spawned process that runs ``evaluate_policy`` for the trainer (the rollout workers' spawn context:
    the training script is not re-imported, BLAS pinned to one thread), so the episodes' Python never holds
    the learner process's interpreter lock. ``evaluate`` blocks its (evaluator) thread without holding the
    lock; a ``stop`` set meanwhile ends the child's episodes at their next step (:class:`StopRequested`)."""

    _POLL_S = 0.1

    def __init__(self) -> None:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        from unilab_jax.runtime.spawn import hidden_main, worker_environment

        ctx = multiprocessing.get_context("spawn")
        self._stop = ctx.Event()
        self._pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_child_init,
                                         initargs=(self._stop,))
        with hidden_main(), worker_environment(1):  # the child starts at the first submit
            self._pool.submit(_child_ready)

    def evaluate(self, job: dict[str, Any], stop: threading.Event | None = None) -> dict[str, float]:
        """``evaluate_policy(**job)`` in the child (``job``'s algorithm as a module name)."""
        future = self._pool.submit(_child_evaluate, job)
        while True:
            if stop is not None and stop.is_set():
                self._stop.set()
            try:
                return future.result(timeout=self._POLL_S)
            except TimeoutError:
                continue

    def close(self) -> None:
        self._stop.set()
        self._pool.shutdown(wait=True, cancel_futures=True)


def fps_of(spec: Any) -> int:
    """Real-time frame rate of a video with one frame per control step of a task with this TaskSpec."""
    return max(1, round(1.0 / spec.ctrl_dt))


def video_writer_missing() -> str | None:
    """None where ``write_video`` can write an mp4, else why not (imageio's ffmpeg plugin needs imageio-ffmpeg,
    which brings the ffmpeg binary; without it imageio would pick another plugin for ".mp4")."""
    try:
        import imageio  # noqa: F401
        import imageio_ffmpeg  # noqa: F401
    except ImportError as e:
        return f"writing an mp4 needs imageio and imageio-ffmpeg ({e}): pip install 'unilab-jax[video]'"
    return None


def write_video(frames: np.ndarray, path: str, fps: int) -> None:
    """Writes frames [T, H, W, 3] uint8 as an H.264 mp4 (the ffmpeg binary comes with imageio-ffmpeg)."""
    import warnings

    if (missing := video_writer_missing()) is not None:
        raise RuntimeError(missing)
    import imageio.v2 as imageio

    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.shape[0] == 0:
        raise ValueError(f"frames must be [T > 0, H, W, 3], got shape {frames.shape}")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    # macro_block_size=1 keeps any frame size (the default pads to multiples of 16 with a warning)
    with warnings.catch_warnings():  # jax warns on any fork once imported; the ffmpeg child only execs
        warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
        with imageio.get_writer(path, format="FFMPEG", fps=fps, codec="libx264", macro_block_size=1,
                                pixelformat="yuv420p", ffmpeg_log_level="error") as writer:
            for f in frames.astype(np.uint8, copy=False):
                writer.append_data(f)


class ClipRecorder:
    """``--video_every``: while training, a clip of one evaluation episode every ``every`` env steps, recorded in
    a background thread on a snapshot of the weights (the deterministic policy, env 0 of a fresh one-env
    instance of the task, at most ``MAX_CLIP_S`` seconds), written to ``<logdir>/videos/step_<N>.mp4`` and to
    TensorBoard as ``eval/clip``: a strip of ``STRIP_FRAMES`` frames side by side (tensorboardX's
    ``add_video`` needs moviepy, which is not a dependency). A clip still waiting when a newer one is due is
    replaced by it, so slow rendering never queues up; a failed clip is logged, training goes on."""

    MAX_CLIP_S = 10.0
    STRIP_FRAMES = 8
    WIDTH, HEIGHT = 320, 240

    def __init__(self, trainer: Any, every: int, start_step: int = 0):
        from concurrent.futures import ThreadPoolExecutor

        if every < 1:
            raise ValueError(f"video_every must be positive, got {every}")
        self._trainer, self.every = trainer, int(every)
        self.next_step = start_step + self.every
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="clip")
        self._futures: list[Any] = []
        self.directory = os.path.join(trainer.run.logdir, "videos")

    def due(self, env_steps: int) -> bool:
        """Whether a clip is due at ``env_steps`` (then the next one is scheduled ``every`` steps later)."""
        if env_steps < self.next_step:
            return False
        while self.next_step <= env_steps:
            self.next_step += self.every
        return True

    def submit(self, weights: dict, env_steps: int) -> None:
        if self._futures and self._futures[-1].cancel():
            self._futures.pop()
        self._futures.append(self._pool.submit(self._record, weights, env_steps))

    def _record(self, weights: dict, env_steps: int) -> str | None:
        import tasks

        tr = self._trainer
        try:
            task = tasks.make(tr.run.task, num_envs=1, seed=10_000 + env_steps, overrides=tr.task_overrides)
            try:
                frames, _ = run_episodes(task, deterministic_policy(tr.algo, weights, task),
                                         max_steps=max(1, round(self.MAX_CLIP_S / tr.spec.ctrl_dt)),
                                         render=(self.WIDTH, self.HEIGHT))
            finally:
                task.close()
            path = os.path.join(self.directory, f"step_{env_steps}.mp4")
            write_video(frames, path, fps_of(tr.spec))
            pick = np.linspace(0, len(frames) - 1, min(self.STRIP_FRAMES, len(frames))).round().astype(int)
            tr.logger.image(env_steps, "eval/clip", np.concatenate(list(frames[pick]), axis=1))
            return path
        except Exception:  # a clip is a view on training, never a reason to stop it
            log.exception("clip at env step %d failed", env_steps)
            return None

    def close(self, cancel: bool = False) -> list[str]:
        """Waits for the clip being recorded (and the waiting one unless ``cancel``); returns the files written."""
        self._pool.shutdown(wait=True, cancel_futures=cancel)
        return [f.result() for f in self._futures if not f.cancelled() and f.result() is not None]


class AsyncEvaluator:
    """Deterministic evaluations in a background thread on a snapshot of the weights, so lock-step
    workers are not held up. ``eval/wall_s`` is when the snapshot was taken (the training time that
    produced the policy); ``eval/done_wall_s`` when its evaluation finished.

    At most one evaluation waits behind the running one: a newer snapshot replaces a waiting one (an
    evaluation slower than ``--eval_every`` would otherwise queue without bound and hold the end of
    the run for minutes); ``skipped`` counts the replaced ones. ``close(cancel=True)`` (an interrupted
    run) drops the waiting one. An evaluation that robot tasks interrupt more often than ``run_episodes``
    starts over (lost robots; a protective stop ends only its robot's episode) is dropped with a warning
    (``interrupted`` counts them): it ends no run, nor does an evaluation process that died (``lost`` counts
    what it took). ``in_process``: the episodes run in an :class:`EvaluationProcess` (the thread only waits).
    """

    def __init__(self, trainer: Any, stop: threading.Event | None = None, in_process: bool = False):
        """``stop``: when set, the running evaluation ends at its next env step (its result is dropped)."""
        from concurrent.futures import ThreadPoolExecutor

        self._trainer, self._stop = trainer, stop
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="eval")
        self._process = EvaluationProcess() if in_process else None
        self._futures: list[Any] = []
        self.skipped = 0
        self.interrupted = 0  # evaluations the robots interrupted past MAX_EVAL_RESTARTS (dropped, logged)
        self.lost = 0  # evaluations lost with a dead evaluation process (logged; the run goes on)

    def submit(self, weights: dict, counters: dict[str, int], wall_s: float) -> None:
        if self._futures and self._futures[-1].cancel():  # still waiting: replace it with the newer snapshot
            self._futures.pop()
            self.skipped += 1
            log.warning("evaluation at an earlier step skipped: evaluations are slower than --eval_every "
                        "(%d skipped so far)", self.skipped)
        self._futures.append(self._pool.submit(self._run, weights, counters, wall_s))

    def _run(self, weights: dict, counters: dict[str, int], wall_s: float) -> dict[str, float] | None:
        from tasks.base import StepInterrupted

        tr = self._trainer
        try:
            result = (self._process.evaluate(tr.evaluation_job(weights, counters["updates"]), self._stop)
                      if self._process is not None else tr.evaluate(weights, seed=counters["updates"], stop=self._stop))
        except StepInterrupted as e:  # robots that stopped the episodes more than run_episodes starts them over
            self.interrupted += 1
            log.warning("evaluation at env step %d dropped: the robots interrupted it %d times (%s)",
                        counters["env_steps"], MAX_EVAL_RESTARTS + 1, e)
            return None
        except BrokenProcessPool as e:  # the evaluation process died (killed, out of memory): its evaluations are lost
            self.lost += 1
            log.error("evaluation at env step %d lost: the evaluation process is gone (%s)", counters["env_steps"], e)
            return None
        result.update({"eval/wall_s": wall_s, "eval/done_wall_s": time.time() - tr.t0,
                       "eval/skipped": float(self.skipped)})
        tr.logger.log(counters["env_steps"], result)
        print(evaluation_line(counters["env_steps"], result), flush=True)
        return result

    def close(self, cancel: bool = False) -> dict[str, float]:
        """Waits for the running evaluation (and the waiting one unless ``cancel``; a stopped run's
        evaluation ends at its next step); returns the newest finished result ({} if none finished)."""
        self._pool.shutdown(wait=True, cancel_futures=cancel)
        if self._process is not None:
            self._process.close()
        done = [f for f in self._futures if not f.cancelled() and not isinstance(f.exception(), StopRequested)
                and f.result() is not None]
        return done[-1].result() if done else {}
