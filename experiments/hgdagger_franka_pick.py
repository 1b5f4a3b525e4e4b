"""HG-DAgger on pick-and-place through robot servers, the scripted expert acting as the operator.

    python experiments/hgdagger_franka_pick.py --robots=sim:franka_emika_panda --speed=20 \\
        --total_steps=2000 --logdir=runs/hgdagger_pick

``unilab_jax/training/hgdagger.py``: whole-episode demonstrations by the operator, a behaviour-cloned novice
(``--demo_episodes``, ``--bc_steps`` gradient steps, ``--bc_weight_decay``, ``--bc_ensemble`` networks acting
their mean), then ``--rounds`` rounds of
``--episodes_per_round`` episodes in which the operator takes over when the novice leaves the safe region,
drops the cube or stalls (``--operator_segment`` steps per takeover, ``--operator_stall_steps``), only the
operator's segments joining the dataset (``--intervention_weight`` times each), and a refit
(``--refit_steps``, from fresh parameters unless ``--warm_start`` fine-tunes the previous novice; ``--keep_best``
drops a refit that evaluates worse); the novice is evaluated alone on ``--eval_episodes`` after every fit.
``--total_steps`` (default 40000) caps the robot steps of the whole run; ``--seed``, ``--logdir``,
``--robots`` and ``--speed`` are the shared flags (``unilab_jax.apps.cli``, ``unilab_jax.apps.robot_cli``). The loop
drives the task in this process (one env per robot of ``--robots``: a comma list or ``.toml`` inventory;
``sim:NAME`` robots are started here at ``--speed``, ``tcp://HOST:PORT`` robots are servers already
running); the operator runs beside the robot clients, so remote robots work the same. Logs:
``metrics.jsonl`` / TensorBoard in ``--logdir``
(``eval/success_rate``, ``hgdagger/intervention_rate``, ...), and ``summary.json``.
"""

import json
import os
import signal
import sys

from absl import app, flags
from absl import logging as absl_logging

from unilab_jax.apps.robot_cli import FLAGS, report_robots, robot_entries

flags.DEFINE_integer("demo_episodes", 24, "operator demonstrations for the initial behaviour-cloned policy")
flags.DEFINE_integer("rounds", 5, "HG-DAgger rounds (gated collection, aggregation, refit)")
flags.DEFINE_integer("episodes_per_round", 32, "gated episodes per round")
flags.DEFINE_integer("eval_episodes", 40, "episodes of each evaluation of the novice alone")
flags.DEFINE_integer("operator_segment", 20, "control steps the operator drives per takeover")
flags.DEFINE_integer("operator_stall_steps", 15, "novice steps without reward progress before a takeover")
flags.DEFINE_integer("bc_steps", 4000, "behaviour-cloning gradient steps of the initial fit")
flags.DEFINE_integer("refit_steps", 4000, "gradient steps of each round's refit")
flags.DEFINE_float("bc_weight_decay", 1.0, "AdamW weight decay of every fit (0.1 gives a novice that never succeeds)")
flags.DEFINE_integer("intervention_weight", 1, "times each operator row of a round enters the aggregate")
flags.DEFINE_bool("warm_start", False, "fine-tune the previous novice in each refit (else fresh parameters)")
flags.DEFINE_bool("keep_best", True, "drop a refit whose evaluation falls below the kept novice's")
flags.DEFINE_string("bc_hidden", "256,256", "behaviour-cloning MLP hidden sizes")
flags.DEFINE_bool("novice_time", False, "the novice reads the episode time (else its observation lacks it)")
flags.DEFINE_integer("bc_ensemble", 5, "networks of the novice (fitted from different seeds; it acts their mean)")
TOTAL_STEPS = 40_000  # robot steps of the whole run (demonstrations, rounds, evaluations) without --total_steps


def validate():
    """The robot inventory and the loop's configuration; ``ValueError`` names a bad flag."""
    from unilab_jax.algos.imitation.bc import BCConfig
    from unilab_jax.robots.operator import OperatorConfig
    from unilab_jax.training.hgdagger import HGDaggerConfig

    entries = robot_entries()
    hidden = tuple(int(h) for h in FLAGS.bc_hidden.split(","))
    config = HGDaggerConfig(demo_episodes=FLAGS.demo_episodes, rounds=FLAGS.rounds,
                            episodes_per_round=FLAGS.episodes_per_round, eval_episodes=FLAGS.eval_episodes,
                            max_env_steps=FLAGS.total_steps or TOTAL_STEPS, warm_start=FLAGS.warm_start,
                            refit_steps=FLAGS.refit_steps, intervention_weight=FLAGS.intervention_weight,
                            keep_best=FLAGS.keep_best, novice_time=FLAGS.novice_time,
                            bc=BCConfig(hidden=hidden, steps=FLAGS.bc_steps, weight_decay=FLAGS.bc_weight_decay,
                                          ensemble=FLAGS.bc_ensemble))
    OperatorConfig(segment_steps=FLAGS.operator_segment, stall_steps=FLAGS.operator_stall_steps)
    return entries, config


def main(argv):
    if len(argv) > 1:
        raise app.UsageError(f"unexpected arguments: {argv[1:]}")
    absl_logging.set_verbosity(absl_logging.WARNING)
    try:
        entries, config = validate()
    except ValueError as e:  # a bad flag: exit 2 before any robot starts
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    import tasks
    from unilab_jax.robots import inventory
    from unilab_jax.training.hgdagger import HGDagger

    with inventory.Inventory(entries, "pick_place", FLAGS.speed, seed=FLAGS.seed) as inv:
        report_robots(inv, "pick_place")
        task = tasks.make("robot_pick_place", len(inv.addresses), FLAGS.seed,
                          {**inv.task_overrides(), "operator_segment": FLAGS.operator_segment,
                           "operator_stall_steps": FLAGS.operator_stall_steps})
        try:
            summary = HGDagger(task, config, seed=FLAGS.seed, logdir=FLAGS.logdir).run()
        finally:
            task.close()
    if FLAGS.logdir:
        with open(os.path.join(FLAGS.logdir, "summary.json"), "w") as f:
            json.dump(summary, f, indent=2)
    print(json.dumps(summary, indent=2))


def _terminate(signum, frame):
    raise KeyboardInterrupt  # unwinds through Inventory, which stops the servers this run started


def _help() -> str:
    from unilab_jax.apps import cli_help

    return cli_help.text(__doc__, [cli_help.flag_lines("flags", ["robots", "speed", "total_steps", "seed", "logdir",
                                                                  *cli_help.script_flags()],
                                                       {"total_steps": TOTAL_STEPS})])


if __name__ == "__main__":
    from unilab_jax.apps.cli_help import exit_on_help

    exit_on_help(_help)
    signal.signal(signal.SIGTERM, _terminate)
    app.run(main)
