"""Robots as resources: one contract for physical, simulated and remote arms.

* ``interface``: ``Robot`` (connect / reset / step / estop / clear_estop / health / close), ``RobotSpec``,
  ``Health``, ``Step`` and the errors (``RobotDisconnected``, ``RobotEstopped``, ``RobotClaimed``, ...).
* ``sim``: ``SimRobot(SimConfig(arm, task, speed, latency_s, ...))``, MuJoCo arms that behave like hardware.
* ``scenes`` / ``ik`` / ``manipulation`` / ``experts``: Menagerie arm scenes (Franka; UR5e + Robotiq 2F-85),
  damped-least-squares IK, the manipulation tasks (peg insertion and pick-and-place, ``robots/manipulation.py``)
  and scripted experts.
* ``server`` / ``client`` / ``protocol`` / ``serve``: a robot server process per robot over ZeroMQ
  (``python -m unilab_jax.robots.serve --robot=franka --task=pick_place --port=5555``) and
  ``RobotClient(address)``, which implements ``Robot``; ``access`` (claims owned by a secret token and the
  client's key, rate limits, the ZAP handler that admits allow-listed CURVE keys) and ``keys``
  (``python -m unilab_jax.robots.keys``: key pairs).
* ``limits``: ``SafetyLimits``, the workspace box, orientation cone, joint and tcp speed and contact-force
  limits a robot enforces on every step (protective stops), counted in ``Health.limit_hits``.
* ``inventory``: which robots a run uses (``--robots``), local simulated servers for them, discovery.
* ``operator`` / ``teleop``: the operator channel (a person or the scripted expert overriding the policy)
  and teleoperation devices.
* ``gl``: which offscreen OpenGL backend renders here.
* ``record``: only the command ``python -m unilab_jax.robots.record``, kept at its documented name; it
  forwards to ``unilab_jax.apps.record`` (the applications wing), which holds the code.

Layering: apart from that forwarder, this package imports numpy, mujoco (+ mujoco_menagerie to locate
models), zmq, msgpack and the standard library only; never jax, mlx, the tasks, the trainer, the runtime or
the algorithms (tests/test_layers.py: the robots are the lowest sub-layer of the resources, the forwarder
sits above the applications it forwards to). Importing the package itself imports nothing.
"""
