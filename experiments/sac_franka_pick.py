"""State-based SAC on pick-and-place through robot servers (robots as resources, docs/ROBOTS.md).

    python experiments/sac_franka_pick.py --robots=sim:franka_emika_panda,sim:universal_robots_ur5e \\
        --speed=20 --total_steps=3000 --logdir=runs/sac_pick

``--robots``: a comma list or a ``.toml`` inventory (``unilab_jax.robots.inventory``): ``sim:NAME`` robots are
started here as local robot servers (``--speed`` times real time, dense reward, no cameras; stopped at exit),
``tcp://HOST:PORT`` robots are servers already running. Each server is asked for its spec and health first.
Assignment: one robot per rollout worker (``--num_workers`` defaults to, and ``auto`` is, the number of robots,
``--envs_per_worker`` to 1); each worker claims the first free robot of the inventory. A robot lost
mid-run stops its worker until the robot (or another free one) answers again; the other workers go on,
and the interrupted step writes no transition. The policy sees the robot's proprioception, its kind
and its place in the inventory; the critic also the privileged object state. Learning shows while it
trains: ``episode/success_rate`` is the success rate of the workers' recent (stochastic) episodes.
The deterministic evaluation runs at the end only (the workers hold every robot while training), on
``--eval_envs`` (default: all) robots once the workers have released them, or on those that answer
within 10 s if some are gone for good (``eval/episodes`` says how many).
"""

import signal

from robot_flags import report_robots, robot_entries

from unilab_jax.cli import FLAGS, PROCESS_START, FlagError, build_run, launch

EVAL_CONNECT_S = 10.0  # how long the end-of-run evaluation waits for robots before going on with those that answer
RECIPE = {"actor_hidden": (64, 64), "critic_hidden": (64, 64), "batch_size": 128, "updates_per_call": 8,
          "publish_every": 8, "utd": 0.5, "learning_starts": 500, "replay_capacity": 200_000,
          "actor_learning_rate": 1e-3, "critic_learning_rate": 1e-3, "alpha_learning_rate": 1e-3, "gamma": 0.95}


def validate(algo: str = "sac", recipe: dict = RECIPE):
    """Checks the flags (the robot flags, then ``build_run``'s for ``algo`` with ``recipe``)."""
    try:
        entries = robot_entries()
    except ValueError as e:
        raise FlagError(str(e)) from e
    n = len(entries)
    for name, value in (("num_workers", n), ("envs_per_worker", 1), ("eval_envs", n)):
        if not FLAGS[name].present or FLAGS[name].value == "auto":  # machine-sized here: one worker per robot
            setattr(FLAGS, name, value)
    if FLAGS.num_workers * FLAGS.envs_per_worker > n:
        raise FlagError(f"--num_workers={FLAGS.num_workers} x --envs_per_worker={FLAGS.envs_per_worker} "
                        f"robots wanted, the inventory has {n}")
    if FLAGS.eval_envs > n:
        raise FlagError(f"--eval_envs={FLAGS.eval_envs}: the inventory has {n} robots")
    if FLAGS.eval_every:
        raise FlagError("--eval_every: the workers hold every robot while training; robot runs evaluate at the end")
    if FLAGS.serial:
        raise FlagError("--serial: robot tasks step robot servers from worker processes")
    run, module, config, task_overrides = build_run(algo, "robot_pick_place", recipe, {}, 50_000)
    if not run.task.startswith("robot_"):
        raise FlagError(f"--task={run.task}: this experiment drives robots (robot_pick_place, robot_peg_insertion)")
    if "robots" in task_overrides:
        raise FlagError("--task_config=robots=...: give the robots with --robots")
    return entries, (run, module, config, task_overrides)


def train(validated) -> None:
    import json

    from unilab_jax.robots import inventory
    from unilab_jax.trainer import Trainer

    entries, (run, module, config, task_overrides) = validated
    robot_task = run.task.removeprefix("robot_")
    with inventory.Inventory(entries, robot_task, FLAGS.speed, seed=FLAGS.seed) as inv:
        report_robots(inv.addresses, robot_task)
        overrides = {**task_overrides, "robots": tuple(inv.addresses)}
        # The end-of-run evaluation runs on the robots that answer then (a robot gone for good is left out).
        summary = Trainer(run, module, config, overrides, start_time=PROCESS_START,
                          eval_overrides={"min_envs": 1, "connect_timeout_s": EVAL_CONNECT_S}).train()
    print(json.dumps(summary, indent=2))
    print(f"logs: {summary['logdir']}  checkpoints: {summary['checkpoints']}")


def _terminate(signum, frame):
    raise KeyboardInterrupt  # unwinds through Inventory, which stops the servers this run started


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, _terminate)
    launch(validate, train)
