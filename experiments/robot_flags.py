"""The robot flags and start-up steps the robot experiments share (``sac_franka_pick.py``,
``sacflow_franka_pick.py``, ``hgdagger_franka_pick.py``): ``--robots`` and ``--speed``, their checks, and
the report of the robots a run found."""

import sys

from absl import flags

flags.DEFINE_string("robots", "sim:franka_emika_panda", "robot inventory: comma list of sim:NAME and "
                    "tcp://HOST:PORT, or a .toml file")
flags.DEFINE_float("speed", 20.0, "wall-clock speed-up of the sim: robots this run starts")
FLAGS = flags.FLAGS


def robot_entries() -> list:
    """The parsed ``--robots`` inventory; ``ValueError`` (with the flag's name) for a bad one or a bad ``--speed``."""
    from unilab_jax.robots import inventory

    try:
        entries = inventory.parse(FLAGS.robots)
    except inventory.InventoryError as e:
        raise ValueError(f"--robots: {e}") from e
    if not FLAGS.speed > 0 or FLAGS.speed == float("inf"):
        raise ValueError(f"--speed must be positive and finite, got {FLAGS.speed}")
    return entries


def report_robots(addresses: list[str], task: str) -> None:
    """Checks every robot of the run (spec, health, one policy for all) and prints it; exits 2 on a problem."""
    from unilab_jax.robots import inventory

    try:
        found = inventory.discover(addresses, task=task)
    except inventory.InventoryError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    for robot in found:
        print(f"robot {robot.address}: {robot.spec.name} ({robot.spec.kind}, {robot.spec.control_hz:g} Hz x "
              f"{robot.spec.speed:g}), health {robot.health.state}", flush=True)
