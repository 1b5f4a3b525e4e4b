"""Robots as resources: one contract for physical, simulated and remote arms.

* ``interface``: ``Robot`` (connect / reset / step / estop / clear_estop / health / close), ``RobotSpec``,
  ``Health``, ``Step`` and the errors (``RobotDisconnected``, ``RobotEstopped``, ``RobotClaimed``, ...).
* ``sim``: ``SimRobot(SimConfig(arm, task, speed, latency_s, ...))``, MuJoCo arms that behave like hardware.
* ``scenes`` / ``ik`` / ``tasks`` / ``experts``: Menagerie arm scenes (Franka; UR5e + Robotiq 2F-85),
  damped-least-squares IK, peg insertion and pick-and-place, scripted experts.
* ``server`` / ``client`` / ``protocol`` / ``serve``: a robot server process per robot over ZeroMQ
  (``python -m unilab_jax.robots.serve --robot=franka --task=pick_place --port=5555``) and
  ``RobotClient(address)``, which implements ``Robot``.
* ``gl``: which offscreen OpenGL backend renders here.

Layering: this package imports numpy, mujoco (+ mujoco_menagerie to locate models), zmq, msgpack and
the standard library only; never jax, mlx, the trainer, the runtime or the algorithms. Importing the
package itself imports nothing.
"""
