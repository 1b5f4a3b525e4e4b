"""The robot experiments' command line (robots as resources, docs/ROBOTS.md): SAC and RLPD on the manipulation
tasks through robot servers. ``experiments/sac_franka_pick.py`` and its siblings (also SAC Flow's) are::

    from unilab_jax.apps.robot_cli import run_robot_experiment
    run_robot_experiment("rlpd", "robot_peg_insertion", RECIPE, default_total_steps=20_000)

Flags beside the shared ones (``unilab_jax.apps.cli``):

* ``--robots``: a comma list or a ``.toml`` inventory (``unilab_jax.robots.inventory``): ``sim:NAME`` robots are
  started here as local robot servers (``--speed`` times real time, rendering the cameras of the image
  observation, else none; stopped at exit; dense reward or success only: ``--dense_reward``, default the
  experiment's), ``tcp://HOST:PORT`` robots are servers already running; a TOML inventory names a keyed server's
  public key (``server_key``) and this client's key pair (``[client] key``), which the workers' clients use
  (docs/ROBOTS.md, "Deploying a robot server"). Each server is asked for its spec and health first (and must
  render the task's cameras at its ``image_size``).
* ``--observation``: what the policy sees besides proprioception: ``images`` (``IMAGE_TASK``: the front and wrist
  cameras' last 2 frames at 32 x 32, uint8, and ``IMAGE_RECIPE``'s small encoder: both sized for a 2-core CPU;
  ``--task_config=cameras=...,image_size=...,frame_stack=...`` and ``--config encoder_channels=...`` change them;
  the critic reads the same images and proprioception, no privileged state: ``critic_state`` off; with
  ``--asymmetric`` the critic also reads the privileged state and the actor has an encoder of its own, trained by
  the actor loss: ``actor_encoder``; a critic with privileged state and a shared encoder is refused),
  ``state`` (``STATE_TASK``: the robot's privileged object state, the state-based comparison) or ``proprio``
  (nothing more); default: the experiment's. Images need an algorithm that learns from them (sac, rlpd, sacflow,
  rlpd_flow: ``algos/offpolicy/image_obs.py``; checked with the image size before any robot starts). With
  images the replay ring holds at most ``--total_steps`` transitions unless ``--config replay_capacity=N`` is given
  (a 64 px transition with two cameras and 2 frames holds 96 KiB of images; the run prints the ring's size in shared
  memory).
* Assignment: one robot per rollout worker (``--num_workers`` defaults to, and ``auto`` is, the number of robots,
  less the ``--eval_envs`` kept for evaluation; ``--envs_per_worker`` to 1); each worker claims the first free robot.
  Periodic evaluation (``--eval_every``) needs robots the workers leave free: ``num_workers x envs_per_worker
  + eval_envs <= robots``. Without ``--eval_every``, evaluation runs at the end on ``--eval_envs`` robots
  (default: all), once the workers have released them. An evaluation runs on the robots that answer within
  ``EVAL_CONNECT_S`` if some are gone for good (``eval/episodes`` says how many).
* ``--algo``: the experiment's algorithm or another that the same learner runs on the same data with another actor
  (``actor_variants``: ``rlpd_flow``, RLPD with SAC Flow's actor, for ``rlpd``; ``sacflow`` for ``sac``).
* Algorithms with prior data (RLPD): ``--demos=DIR``, a replay store of demonstrations
  (``python -m unilab_jax.robots.record``) recorded on the same inventory; without it, ``--num_demos``
  episodes of the scripted expert are recorded on the run's robots first, into ``LOGDIR/demos`` (reused by
  ``--resume``), and their robot time counts towards the run's.

Experiments with their own loop (``hgdagger_franka_pick.py``) use ``robot_entries`` and ``report_robots``.

The summary adds ``robot_s``: robot time at speed 1 (env steps x control period, summed over robots, plus
the demonstrations'), what physical robots would need.
"""

from __future__ import annotations

import dataclasses
import json
import operator
import os
import shutil
import signal
import sys
from collections.abc import Mapping
from types import SimpleNamespace
from typing import Any

from absl import flags

from unilab_jax import algos
from unilab_jax.apps.cli import FLAGS, PROCESS_START, FlagError, build_run, help_text, launch, report
from unilab_jax.recipes import MANIPULATION_RECIPE  # noqa: F401 (the manipulation scripts' recipe, kept here too)

STATE_TASK = {"policy_state": True}
# The policy sees no object or hole pose with images (policy_state off), and the critic none either (critic_state off):
# a critic that knows them trains an encoder that need not locate them, and the actor reads that encoder's features
# (on the reach test such a critic still learned, a bit slower: tests/robots/test_pixel_learning.py).
IMAGE_TASK = {"cameras": ("front", "wrist"), "image_size": 32, "frame_stack": 2, "critic_state": False}
# --asymmetric: the critic also reads the privileged state; the image-only actor gets an encoder of its own.
ASYMMETRIC_TASK, ASYMMETRIC_RECIPE = {"critic_state": True}, {"actor_encoder": True}
# With images, on top of the algorithm's recipe: an encoder of two strided 8-channel convolutions and utd 0.5, so
# that the plain commands finish on a 2-core CPU (RLPD's gradient step at batch 128 there: 13 ms; DrQ's four
# 32-channel convolutions at 64 px: 654 ms; rlpd_franka_peg.py --total_steps=2000: 135-150 s wall). On a GPU:
# --task_config=image_size=64 --config encoder_channels='(32, 32, 32, 32)' --config encoder_strides='(2, 1, 1, 1)'
# --config feature_dim=50 and a higher utd (the GPU commands of docs/dev/GPU_RUNS.md).
IMAGE_RECIPE = {"encoder_channels": (8, 8), "encoder_strides": (2, 2), "feature_dim": 32, "utd": 0.5}
OBSERVATIONS = {"images": IMAGE_TASK, "state": STATE_TASK, "proprio": {}}
# Under every observation: no inventory-slot one-hot. Periodic evaluation runs on the robots the workers leave
# free, slots the policy never trained on (RLPD peg, 12 robots on an H100: eval success 0-0.25 over 60 robot-min
# with the one-hot; the cause: tests/robots/test_robot_identity.py). --task_config=robot_identity=true: with it.
ROBOT_TASK = {"robot_identity": False}
EVAL_CONNECT_S = 10.0  # how long an evaluation waits for robots before going on with those that answer

flags.DEFINE_string("robots", "sim:franka_emika_panda", "robot inventory: comma list of sim:NAME and "
                    "tcp://HOST:PORT, or a .toml file")
flags.DEFINE_float("speed", 20.0, "wall-clock speed-up of the sim: robots this run starts; inf: unpaced (as fast as "
                   "the CPU steps them, so no action is ever late and the machine's load does not change what they do)")
flags.DEFINE_string("demos", "", "prior data (RLPD): a replay store of demonstrations recorded on the same "
                    "inventory; empty: record --num_demos scripted-expert episodes into LOGDIR/demos first")
flags.DEFINE_bool("dense_reward", None, "sim: robots this run starts: dense shaped reward plus the success bonus "
                  "(else 1 on success only); default: the experiment's")
flags.DEFINE_integer("num_demos", 20, "scripted-expert episodes recorded when --demos is not given (RLPD)")
flags.DEFINE_bool("asymmetric", False, "with --observation=images: the critic also reads the privileged state "
                  "(object poses) and the actor, which reads images and proprioception only, has its own encoder")
flags.DEFINE_string("algo", None, "the algorithm: the experiment's or one its learner runs on the same data with "
                    "another actor (rlpd_franka_*.py: rlpd or rlpd_flow; sac_*.py: sac or sacflow); default: the "
                    "experiment's")
flags.DEFINE_enum("observation", None, list(OBSERVATIONS), "what the policy sees besides proprioception: images "
                  "(camera frames), state (the object state) or proprio (nothing else); default: the experiment's")


def robot_entries() -> list:
    """The parsed ``--robots`` inventory; ``ValueError`` (with the flag's name) for a bad one or a bad ``--speed``."""
    from unilab_jax.robots import inventory

    try:
        entries = inventory.parse(FLAGS.robots)
    except inventory.InventoryError as e:
        raise ValueError(f"--robots: {e}") from e
    if not FLAGS.speed > 0:  # nan too; inf: unpaced
        raise ValueError(f"--speed must be positive (inf: unpaced), got {FLAGS.speed}")
    return entries


def report_robots(inv: Any, task: str) -> list:
    """Checks every robot of the inventory ``inv`` (a started ``robots.inventory.Inventory``: spec, health, one
    policy for all), prints and returns them (``inventory``'s discovery); exits 2 on a problem."""
    from unilab_jax.robots import inventory

    try:
        found = inventory.discover(inv.addresses, task=task, keyring=inv.keyring())
    except inventory.InventoryError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    for robot in found:
        print(f"robot {robot.address}: {robot.spec.name} ({robot.spec.kind}, {robot.spec.control_hz:g} Hz x "
              f"{robot.spec.speed:g}), health {robot.health.state}", flush=True)
    return found


def actor_variants(algo: str) -> list[str]:
    """The registered algorithms that ``--algo`` may put in place of ``algo``: those the same learner runs ("update")
    on the same data (prior data, images), which differ from it in their actor (rlpd: rlpd, rlpd_flow)."""
    key = operator.attrgetter("update", "prior_data", "images")
    return [name for name in algos.names() if key(algos.info(name)) == key(algos.info(algo))]


def _validate(algo: str, task: str, recipe: Mapping[str, Any], task_recipe: Mapping[str, Any],
              default_total_steps: int, observation: str) -> tuple:
    import tasks
    from unilab_jax.config import apply_overrides, parse_overrides

    if FLAGS.algo is not None:
        variants = actor_variants(algo)
        if FLAGS.algo not in variants:
            raise FlagError(f"--algo={FLAGS.algo!r}: this experiment runs {' or '.join(variants)}")
        algo = FLAGS.algo
    try:
        entries = robot_entries()
    except ValueError as e:
        raise FlagError(str(e)) from e
    images = (FLAGS.observation or observation) == "images"
    if FLAGS.asymmetric and not images:
        raise FlagError("--asymmetric: with --observation=images only (without images the critic reads the privileged "
                        "state anyway)")
    asymmetric = FLAGS.asymmetric and images
    task_recipe = {**ROBOT_TASK, **OBSERVATIONS[FLAGS.observation or observation], **task_recipe,
                   **(ASYMMETRIC_TASK if asymmetric else {})}
    recipe = {**recipe, **(IMAGE_RECIPE if images else {}), **(ASYMMETRIC_RECIPE if asymmetric else {})}
    n = len(entries)
    periodic = FLAGS.eval_every > 0
    if not FLAGS["eval_envs"].present:
        FLAGS.eval_envs = 1 if periodic else n
    # machine-sized here (also for ``auto``): one worker per training robot
    if not FLAGS["envs_per_worker"].present or FLAGS.envs_per_worker == "auto":
        FLAGS.envs_per_worker = 1
    if not FLAGS["num_workers"].present or FLAGS.num_workers == "auto":
        FLAGS.num_workers = max(n - FLAGS.eval_envs, 1) if periodic else n
    training = FLAGS.num_workers * FLAGS.envs_per_worker
    if training > n:
        raise FlagError(f"--num_workers={FLAGS.num_workers} x --envs_per_worker={FLAGS.envs_per_worker} "
                        f"robots wanted, the inventory has {n}")
    if FLAGS.eval_envs > n:
        raise FlagError(f"--eval_envs={FLAGS.eval_envs}: the inventory has {n} robots")
    if periodic and training + FLAGS.eval_envs > n:
        raise FlagError(f"--eval_every: the workers hold {training} robots and evaluation needs {FLAGS.eval_envs} "
                        f"more; the inventory has {n} (add robots or evaluate at the end only)")
    if FLAGS.serial:
        raise FlagError("--serial: robot tasks step robot servers from worker processes")
    run, module, config, task_overrides = build_run(algo, task, recipe, task_recipe, default_total_steps)
    if not run.task.startswith("robot_"):
        raise FlagError(f"--task={run.task}: this experiment drives robots (robot_pick_place, robot_peg_insertion)")
    task_config = apply_overrides(tasks.default_config(run.task), task_overrides)
    image_shape = task_config.image_shape()
    if image_shape:  # the algorithm learns from images of this size (a learner checks it again when it is built)
        from unilab_jax.algos.offpolicy.image_obs import check_algo

        try:
            check_algo(module, SimpleNamespace(name=run.task, image_shape=image_shape), config)
        except ValueError as e:
            raise FlagError(f"--observation=images: {e}") from e
    if image_shape and task_config.critic_state and not config.actor_encoder:
        raise FlagError("--observation=images with a critic that reads the privileged state (critic_state) needs the "
                        "actor's own encoder (actor_encoder): use --asymmetric")
    if image_shape and "replay_capacity" not in parse_overrides(FLAGS.config):
        # images make a transition ~100x larger: the ring holds the run's steps at most (all of them, once)
        config = dataclasses.replace(config, replay_capacity=min(config.replay_capacity, run.total_steps))
    if {"robots", "server_keys", "client_key"} & set(task_overrides):
        raise FlagError("--task_config=robots/server_keys/client_key=...: give the robots and their keys with --robots")
    prior = algos.info(module).prior_data
    if not prior and (FLAGS.demos or FLAGS["num_demos"].present):
        raise FlagError(f"--demos / --num_demos: {algo} learns without prior data")
    if FLAGS.demos and not os.path.isfile(os.path.join(FLAGS.demos, "index.json")):
        raise FlagError(f"--demos={FLAGS.demos!r}: no replay store there (record one with "
                        "python -m unilab_jax.robots.record)")
    if prior and FLAGS.num_demos < 1:
        raise FlagError(f"--num_demos must be positive, got {FLAGS.num_demos}")
    return entries, (run, module, config, task_overrides), task_config


def _demos(inv: Any, run: Any, task_overrides: dict[str, Any]) -> tuple[str, float]:
    """The demonstrations folder and the robot seconds this run spent recording it (0 when given or reused)."""
    from unilab_jax.apps import record

    if FLAGS.demos:
        return os.path.abspath(FLAGS.demos), 0.0
    out = os.path.join(os.path.abspath(run.logdir), "demos")
    if os.path.isfile(os.path.join(out, "index.json")):
        return out, 0.0
    partial = out + ".partial"  # renamed into place once complete: a crash never leaves half a recording
    shutil.rmtree(partial, ignore_errors=True)
    summary = record.record(inv.addresses, run.task, FLAGS.num_demos, partial, "expert", seed=run.seed,
                            overrides={**task_overrides, **inv.task_overrides()})
    os.replace(partial, out)
    print(f"demonstrations: {summary['episodes']} episodes ({summary['successes']} successful, "
          f"{summary['transitions']} transitions, {summary['robot_seconds']:.0f} robot-s) in {out}", flush=True)
    return out, float(summary["robot_seconds"])


def _train(validated: tuple, dense_reward: bool) -> None:
    from unilab_jax.robots import inventory
    from unilab_jax.runtime.prior import PriorDataError
    from unilab_jax.training.trainer import Trainer

    entries, (run, module, config, task_overrides), task_config = validated
    robot_task = run.task.removeprefix("robot_")
    dense = dense_reward if FLAGS.dense_reward is None else FLAGS.dense_reward
    with inventory.Inventory(entries, robot_task, FLAGS.speed, seed=FLAGS.seed, dense_reward=dense,
                             cameras=task_config.cameras, image_size=task_config.image_size,
                             camera_geometry=task_config.camera_geometry) as inv:
        found = report_robots(inv, robot_task)
        if task_config.cameras:
            _check_cameras(found, task_config, config)
        demo_s = 0.0
        if algos.info(module).prior_data:
            prior_dir, demo_s = _demos(inv, run, task_overrides)
            config = dataclasses.replace(config, prior_dir=prior_dir)
        overrides = {**task_overrides, **inv.task_overrides()}
        trainer = Trainer(run, module, config, overrides, start_time=PROCESS_START,
                          eval_overrides={"min_envs": 1, "connect_timeout_s": EVAL_CONNECT_S})
        try:
            summary = trainer.train()
        except PriorDataError as e:  # raised before any worker starts
            print(f"error: --demos: {e}", file=sys.stderr)
            sys.exit(2)
    summary["robot_s"] = summary["env_steps"] / found[0].spec.control_hz + demo_s
    with open(os.path.join(run.logdir, "summary.json"), "w") as f:
        json.dump(summary, f, indent=2)
    report(summary)


def _check_cameras(found: list, task_config: Any, config: Any) -> None:
    """Every robot renders the image observation's cameras at its size (exits 2 if not); prints the image memory."""
    from tasks.robot import camera_mismatch

    for robot in found:
        problem = camera_mismatch(task_config, robot.spec)
        if problem:
            print(f"error: robot {robot.address} ({robot.spec.name}): {problem}", file=sys.stderr)
            sys.exit(2)
    s, c = task_config.image_size, 3 * len(task_config.cameras) * task_config.frame_stack
    per = 2 * s * s * c  # image + next_image, uint8
    print(f"image observation {s}x{s}x{c} uint8 ({','.join(task_config.cameras)} x {task_config.frame_stack} frames): "
          f"{per / 1024:.0f} KiB of images per transition, {config.replay_capacity * per / 2**30:.2f} GiB for "
          f"replay_capacity={config.replay_capacity} in shared memory", flush=True)


def _terminate(signum, frame):
    raise KeyboardInterrupt  # unwinds through Inventory, which stops the servers this run started


def _own_flags() -> list[str]:
    """The flags this module adds to the shared ones (``--robots``, ``--speed`` ...)."""
    from unilab_jax.apps import cli_help

    return cli_help.flags_of(__name__)


def run_robot_experiment(algo: str, task: str, recipe: Mapping[str, Any], default_total_steps: int,
                         task_recipe: Mapping[str, Any] | None = None, dense_reward: bool = True,
                         observation: str = "proprio") -> None:
    """Parses and validates the flags, starts the robots (and records demonstrations), trains, prints the summary.
    ``observation``: the default of ``--observation`` (``OBSERVATIONS``; ``task_recipe`` goes on top)."""
    signal.signal(signal.SIGTERM, _terminate)
    launch(lambda: _validate(algo, task, recipe, task_recipe or {}, default_total_steps, observation),
           lambda validated: _train(validated, dense_reward), errors=(ValueError,),  # config checks: exit 2
           help=lambda: help_text(algo, task, recipe,
                                  {**ROBOT_TASK, **OBSERVATIONS[observation], **(task_recipe or {})},
                                  default_total_steps, extra_flags=tuple(_own_flags()),
                                  defaults={"observation": observation, "dense_reward": dense_reward}))
