"""Arm scenes built with ``mujoco.MjSpec`` from MuJoCo Menagerie models (``MENAGERIE_ROOT`` for offline copies).

Both arms stand at the world origin on a floor that serves as the table (z = 0). Each scene gets:

* a ``tcp`` site between the fingertips with the same convention on every arm (z: approach direction,
  y: finger opening direction), which end-effector control tracks;
* gravity compensation on the arm's bodies (as the robots' own controllers do);
* a world-fixed ``front`` camera and a ``wrist`` camera on the hand.

``ARMS[name]`` describes where the joints, actuators and gripper are; ``build_arm(name)`` returns the
editable spec (tasks add their objects before compiling).
"""

from __future__ import annotations

import dataclasses
import os

import mujoco
import numpy as np


@dataclasses.dataclass(frozen=True)
class ArmInfo:
    """Names inside a compiled arm scene and the gripper's actuator range.

    ``gripper_open`` / ``gripper_closed``: actuator controls for a fully open / closed gripper.
    ``home_tcp``: the tcp position [3] every episode starts near (orientation: pointing down).
    """

    kind: str
    joints: tuple[str, ...]
    actuators: tuple[str, ...]
    gripper_actuator: str
    gripper_open: float
    gripper_closed: float
    gripper_joints: tuple[str, ...]  # joints whose positions measure the opening
    gripper_joint_open: tuple[float, ...]  # their positions when fully open
    gripper_joint_closed: tuple[float, ...]
    hand_body: str
    tcp_local: tuple[float, float, float]  # tcp site position in the hand body's frame
    home_qpos: tuple[float, ...]  # arm joint seed for the home pose solve


ARMS: dict[str, ArmInfo] = {
    "franka": ArmInfo(
        kind="franka",
        joints=tuple(f"joint{i}" for i in range(1, 8)),
        actuators=tuple(f"actuator{i}" for i in range(1, 8)),
        gripper_actuator="actuator8",
        gripper_open=255.0,
        gripper_closed=0.0,
        gripper_joints=("finger_joint1",),
        gripper_joint_open=(0.04,),
        gripper_joint_closed=(0.0,),
        hand_body="hand",
        tcp_local=(0.0, 0.0, 0.1034),
        home_qpos=(0.0, 0.2, 0.0, -2.2, 0.0, 2.4, 0.785),
    ),
    "ur5e": ArmInfo(
        kind="ur5e",
        joints=("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
                "wrist_3_joint"),
        actuators=("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"),
        gripper_actuator="gripper/fingers_actuator",
        gripper_open=0.0,
        gripper_closed=255.0,
        gripper_joints=("gripper/right_driver_joint",),
        gripper_joint_open=(0.0,),
        gripper_joint_closed=(0.8,),
        hand_body="gripper/base",
        tcp_local=(0.0, 0.0, 0.145),
        home_qpos=(3.1416, -1.9, 2.0, -1.67, -1.5708, 0.0),
    ),
}

HOME_TCP = (0.45, 0.0, 0.25)
FRANKA_GRIP_GAIN = 4.0
# tcp pointing down, fingers opening along world y: rotation by pi about world x.
HOME_TCP_QUAT = (0.0, 1.0, 0.0, 0.0)


def menagerie_spec(robot: str, variant: str) -> mujoco.MjSpec:
    """A Menagerie model's ``variant`` XML as an editable MjSpec (``MENAGERIE_ROOT`` for offline copies)."""
    import mujoco_menagerie

    root = os.environ.get("MENAGERIE_ROOT")
    if root and not os.path.isdir(root):
        raise FileNotFoundError(f"MENAGERIE_ROOT={root!r} is not a directory")
    return mujoco_menagerie.get(robot).spec(variant)


def _franka() -> mujoco.MjSpec:
    spec = menagerie_spec("franka_emika_panda", "panda")
    for key in list(spec.keys):
        spec.delete(key)
    spec.body("hand").add_site(name="tcp", pos=list(ARMS["franka"].tcp_local), size=[0.005] * 3, group=5)
    # Menagerie's finger servo (kp 100 N/m on the finger tendon) squeezes a 4 cm object with ~2 N; the
    # real gripper holds up to 70 N. Four times the gains (same force limit) keep grasps from slipping.
    grip = spec.actuator(ARMS["franka"].gripper_actuator)
    grip.gainprm[0] *= FRANKA_GRIP_GAIN
    grip.biasprm[1] *= FRANKA_GRIP_GAIN
    grip.biasprm[2] *= FRANKA_GRIP_GAIN
    return spec


def _ur5e() -> mujoco.MjSpec:
    spec = menagerie_spec("universal_robots_ur5e", "ur5e")
    gripper = menagerie_spec("robotiq_2f85", "2f85")
    for s in (spec, gripper):
        for key in list(s.keys):
            s.delete(key)
    spec.option.cone = gripper.option.cone
    spec.option.impratio = gripper.option.impratio
    spec.attach(gripper, prefix="gripper/", site=spec.site("attachment_site"))
    # The 2F-85's pinch point lies between the pads; its frame already has z along the approach and
    # the fingers closing along y.
    spec.body("gripper/base").add_site(name="tcp", pos=list(ARMS["ur5e"].tcp_local), size=[0.005] * 3, group=5)
    return spec


def _add_world(spec: mujoco.MjSpec, hand_body: str) -> None:
    """Floor/table, lights, cameras, solver settings."""
    spec.option.timestep = 0.002
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    spec.visual.global_.offwidth = 256
    spec.visual.global_.offheight = 256
    spec.visual.quality.offsamples = 0
    world = spec.worldbody
    # The Menagerie models' own lights go (the Franka's: 0.7 from above; the UR5e's follows a link): the scene's light.
    for light in list(spec.lights):
        spec.delete(light)
    # Exposure: a matte floor (no specular highlight) and light that adds up to ~1.2 on a face turned up (ambient,
    # headlight, the two lights), so the brightest object colours (0.75-0.85) stay below saturation. Before, with
    # the Franka model's own 0.7 light on top, MuJoCo's default specular 0.5 on the floor and a brighter headlight,
    # over half of the downward-looking wrist camera's pixels were 250-255 (white floor, pale objects).
    spec.visual.headlight.ambient = [0.2, 0.2, 0.2]
    spec.visual.headlight.diffuse = [0.2, 0.2, 0.2]
    spec.visual.headlight.specular = [0.0, 0.0, 0.0]
    floor = spec.add_material(name="floor", rgba=[0.55, 0.5, 0.45, 1.0], specular=0.0, shininess=0.0,
                              reflectance=0.0)
    world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1.5, 1.5, 0.01], material=floor.name)
    world.add_light(pos=[0.4, 0.0, 1.5], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
                    diffuse=[0.5, 0.5, 0.5], specular=[0.1, 0.1, 0.1])
    world.add_light(pos=[1.2, -0.8, 1.0], dir=[-0.6, 0.5, -0.6], diffuse=[0.3, 0.3, 0.3], specular=[0.1, 0.1, 0.1])
    # Looking at the workspace from the front-left, slightly above.
    world.add_camera(name="front", pos=[1.05, -0.45, 0.55], xyaxes=[0.6, 0.8, 0.0, -0.3, 0.22, 0.93], fovy=50)
    hand = spec.body(hand_body)
    # Wrist camera behind the fingers, looking along the approach (tcp z) direction.
    hand.add_camera(name="wrist", pos=[0.06, 0.0, 0.02], xyaxes=[0, -1, 0, -1, 0, 0], fovy=75)


def _gravity_compensation(spec: mujoco.MjSpec) -> None:
    for body in spec.bodies:
        if body.name != "world":
            body.gravcomp = 1.0


def build_arm(kind: str) -> mujoco.MjSpec:
    """The editable scene of arm ``kind`` (a key of ARMS) with floor, lights, cameras and the tcp site."""
    if kind not in ARMS:
        raise ValueError(f"unknown arm {kind!r}; choose one of {sorted(ARMS)}")
    spec = _franka() if kind == "franka" else _ur5e()
    _gravity_compensation(spec)
    _add_world(spec, ARMS[kind].hand_body)
    return spec


@dataclasses.dataclass(frozen=True)
class ArmIndex:
    """Integer addresses of an arm inside a compiled model."""

    qpos: np.ndarray  # [n_arm] qpos addresses of the arm joints
    dof: np.ndarray  # [n_arm] dof addresses
    ctrl: np.ndarray  # [n_arm] actuator ids of the arm servos
    ctrl_range: np.ndarray  # [n_arm, 2]
    gripper_ctrl: int
    gripper_qpos: np.ndarray  # [k]
    tcp_site: int
    hand_body: int


def index(model: mujoco.MjModel, info: ArmInfo) -> ArmIndex:
    """Looks up every name of ``info`` in ``model`` (raises KeyError naming the missing one)."""
    joints = [model.joint(n) for n in info.joints]
    ctrl = np.array([model.actuator(n).id for n in info.actuators])
    return ArmIndex(
        qpos=np.array([j.qposadr[0] for j in joints]),
        dof=np.array([j.dofadr[0] for j in joints]),
        ctrl=ctrl,
        ctrl_range=model.actuator_ctrlrange[ctrl].copy(),
        gripper_ctrl=model.actuator(info.gripper_actuator).id,
        gripper_qpos=np.array([model.joint(n).qposadr[0] for n in info.gripper_joints]),
        tcp_site=model.site("tcp").id,
        hand_body=model.body(info.hand_body).id,
    )
