"""Drive a policy in the browser: ``python -m unilab_jax.web --policy PATH.onnx [--robot go1] --out DIR``.

Builds a static page in ``DIR`` (no backend: any static file server shows it, e.g.
``python -m http.server -d DIR``; browsers refuse ES modules and WebAssembly from ``file://``) where the
arrow keys set the velocity command of an exported policy (``python -m unilab_jax.export --format onnx``):
up / down the forward speed, left / right the yaw rate. In the page MuJoCo's WebAssembly build
(``@mujoco/mujoco``) steps the robot's task model, onnxruntime-web runs the policy and three.js draws the
model's geoms.

What the page runs is the training task at evaluation, without observation noise or domain randomisation:

* the model is the task's own (``tasks.go1_joystick.build_spec`` of the task config), written as MJCF by
  ``MjSpec.to_xml`` (``model.xml``); the page compiles it with the WebAssembly MuJoCo;
* the observation, action scaling, control decimation and termination are ``web_page/go1.js``, a
  transcription of ``tasks/go1_math.py``'s ``actor_obs`` and the task's ``step`` whose numbers
  ``tests/test_web.py`` compares with the Python task's, step by step;
* the observation normaliser is part of the exported ONNX graph (``apps/export.py``), so the page feeds the
  raw observation.

The task config comes from the policy's sidecar, ``PATH.json`` beside ``PATH.onnx`` when present:
``{"task": "go1_joystick_flat", "task_overrides": {"kp": 35, ...}}`` (the run's task and overrides as its
checkpoint records them) or ``{"task": ..., "task_config": {every field}}``; other keys are ignored. Without a
sidecar the task's defaults apply.

The page's assets come from the npm packages pinned in the repository's ``package.json`` (``npm ci`` in the
repository root installs them into ``node_modules``; ``--node_modules`` points elsewhere). The page exposes
``window.unilab`` (state, observation, ``advance(n)``, ``reset()``, ``setCommand(c)``) for tests; the query
``?speed=max`` runs the simulation as fast as the browser can, ``?speed=0`` leaves it to ``advance``, and
``?view=0`` draws nothing (a browser without a GPU spends most of its time drawing).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import shutil
import sys
from typing import Any

PAGE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "web_page")
REPO_NODE_MODULES = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                                 "node_modules")
# Files copied from node_modules into DIR/vendor: (package, file in the package, name under vendor/).
VENDOR = (
    ("@mujoco/mujoco", "mujoco.js", "mujoco/mujoco.js"),
    ("@mujoco/mujoco", "mujoco.wasm", "mujoco/mujoco.wasm"),
    ("onnxruntime-web", "dist/ort.wasm.min.mjs", "ort/ort.wasm.min.mjs"),
    ("onnxruntime-web", "dist/ort-wasm-simd-threaded.mjs", "ort/ort-wasm-simd-threaded.mjs"),
    ("onnxruntime-web", "dist/ort-wasm-simd-threaded.wasm", "ort/ort-wasm-simd-threaded.wasm"),
    ("three", "build/three.module.js", "three/three.module.js"),
    ("three", "build/three.core.js", "three/three.core.js"),
    ("three", "examples/jsm/controls/OrbitControls.js", "three/addons/controls/OrbitControls.js"),
)
PAGE_FILES = ("index.html", "app.js")


@dataclasses.dataclass(frozen=True)
class PageRobot:
    """A robot the page drives: its task, how its model is built, the page's task module and the key commands."""

    task: str  # the task the policy was trained on
    build_spec: str  # "module:function" making the task's MjSpec from its config
    obs_dim: int
    module: str  # the page's task module (web_page/)
    forward: float  # m/s commanded while up (down: minus) is held
    yaw_rate: float  # rad/s commanded while left (right: minus) is held


ROBOTS = {"go1": PageRobot(task="go1_joystick_flat", build_spec="tasks.go1_joystick:build_spec", obs_dim=48,
                      module="go1.js", forward=1.0, yaw_rate=1.0)}


class WebError(Exception):
    """Bad input to the page builder (exit 2)."""


def read_sidecar(policy: str, robot: PageRobot) -> dict[str, Any]:
    """The task config fields of ``policy``'s sidecar (``PATH.json``: ``task`` and ``task_overrides``, or the whole
    ``task_config``), its task checked against ``robot``'s; {} without a sidecar."""
    path = os.path.splitext(policy)[0] + ".json"
    if not os.path.exists(path):
        return {}
    try:
        with open(path) as f:
            side = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        raise WebError(f"{path}: not a readable JSON sidecar ({e})") from e
    if not isinstance(side, dict):
        raise WebError(f"{path}: expected a JSON object with 'task' and 'task_overrides' or 'task_config'")
    task = side.get("task", robot.task)
    if task != robot.task:
        raise WebError(f"{path}: the policy was trained on task {task!r}; this robot's page runs {robot.task!r}")
    if "task_overrides" in side and "task_config" in side:
        raise WebError(f"{path}: give 'task_overrides' or 'task_config', not both")
    fields = side.get("task_overrides", side.get("task_config", {}))
    if not isinstance(fields, dict):
        raise WebError(f"{path}: the task's config fields must be an object")
    return fields


def check_policy(policy: str, obs_dim: int, action_dim: int) -> None:
    """The ONNX file has input ``obs`` [batch, obs_dim] and output ``action`` [batch, action_dim] (export's form)."""
    import onnx

    try:
        graph = onnx.load(policy).graph
    except Exception as e:  # onnx raises DecodeError and friends for a file that is not a model
        raise WebError(f"{policy}: not an ONNX model ({type(e).__name__}: {e})") from e

    def dims(values: Any) -> dict[str, list]:
        return {v.name: [d.dim_value or d.dim_param for d in v.type.tensor_type.shape.dim] for v in values}

    inputs, outputs = dims(graph.input), dims(graph.output)
    init = {i.name for i in graph.initializer}
    inputs = {k: v for k, v in inputs.items() if k not in init}
    if list(inputs) != ["obs"] or "action" not in outputs:
        raise WebError(f"{policy}: expected input 'obs' and output 'action' (python -m unilab_jax.export), "
                       f"got inputs {list(inputs)} and outputs {list(outputs)}")
    if inputs["obs"][-1] != obs_dim or outputs["action"][-1] != action_dim:
        raise WebError(f"{policy}: obs {inputs['obs']} / action {outputs['action']} do not fit the task's "
                       f"obs_dim {obs_dim} / action_dim {action_dim}")


def model_xml(spec: Any) -> str:
    """``spec`` as MJCF the WebAssembly MuJoCo (an older release than the Python one) compiles.

    MuJoCo 4's writer spells out ``input="pos"`` on general actuators, which is the only input an
    older parser accepts there and which it rejects as an unknown attribute; dropping it keeps the model
    (tests/test_web.py compares the dynamics)."""
    return re.sub(r'(<general\b[^>]*?) input="pos"', r"\1", spec.to_xml())


def page_spec(robot_name: str, overrides: dict[str, Any]) -> tuple[dict[str, Any], str]:
    """(the page's ``task.json``, the model's MJCF) of ``robot_name``'s task under ``overrides``."""
    import mujoco

    import tasks
    from tasks.model_edits import sensor_index
    from unilab_jax import lazy
    from unilab_jax.config import ConfigError, apply_overrides

    robot = ROBOTS[robot_name]
    try:
        config = apply_overrides(tasks.default_config(robot.task), overrides)
    except ConfigError as e:
        raise WebError(f"task overrides: {e}") from e
    nsub = round(config.ctrl_dt / config.sim_dt)
    if nsub < 1 or abs(nsub * config.sim_dt - config.ctrl_dt) > 1e-9:
        raise WebError(f"ctrl_dt {config.ctrl_dt} must be a multiple of sim_dt {config.sim_dt}")
    spec = lazy.load(robot.build_spec)(config)
    model = spec.compile()
    home = model.key("home")
    index = sensor_index(model)
    page = {
        "robot": robot_name, "task": robot.task, "module": robot.module, "model": "model.xml",
        "policy": "policy.onnx", "obs_dim": robot.obs_dim, "action_dim": int(model.nu),
        "ctrl_dt": config.ctrl_dt, "nsub": nsub, "action_scale": config.action_scale,
        "home_qpos": [float(v) for v in home.qpos], "default_pose": [float(v) for v in home.qpos[7:]],
        "sensors": {k: list(index[k]) for k in ("local_linvel", "gyro", "orientation", "upvector")},
        "keys": {"forward": min(robot.forward, config.command_a[0]),
                 "yaw_rate": min(robot.yaw_rate, config.command_a[2])},
        "mujoco": mujoco.__version__, "task_overrides": overrides,
    }
    return page, model_xml(spec)


def build(policy: str, out: str, robot: str = "go1", node_modules: str = REPO_NODE_MODULES) -> dict[str, Any]:
    """Writes the page for ``policy`` into ``out``; returns what it wrote."""
    if robot not in ROBOTS:
        raise WebError(f"--robot={robot!r}: choose one of {', '.join(ROBOTS)}")
    if not os.path.isfile(policy):
        raise WebError(f"--policy={policy!r}: no such file")
    missing = [os.path.join(pkg, f) for pkg, f, _ in VENDOR if not os.path.isfile(os.path.join(node_modules, pkg, f))]
    if missing:
        raise WebError(f"{node_modules} lacks {missing[0]}: run `npm ci` in the repository root (or pass "
                       "--node_modules)")
    page, xml = page_spec(robot, read_sidecar(policy, ROBOTS[robot]))
    check_policy(policy, page["obs_dim"], page["action_dim"])
    os.makedirs(out, exist_ok=True)
    for name in (*PAGE_FILES, page["module"]):
        shutil.copyfile(os.path.join(PAGE_DIR, name), os.path.join(out, name))
    for pkg, f, dest in VENDOR:
        target = os.path.join(out, "vendor", dest)
        os.makedirs(os.path.dirname(target), exist_ok=True)
        shutil.copyfile(os.path.join(node_modules, pkg, f), target)
    shutil.copyfile(policy, os.path.join(out, page["policy"]))
    with open(os.path.join(out, page["model"]), "w") as f:
        f.write(xml)
    with open(os.path.join(out, "task.json"), "w") as f:
        json.dump(page, f, indent=1)
    versions = {}
    for pkg in sorted({pkg for pkg, _, _ in VENDOR}):
        with open(os.path.join(node_modules, pkg, "package.json")) as f:
            versions[pkg] = json.load(f)["version"]
    return {"out": os.path.abspath(out), "robot": robot, "task": page["task"], "npm": versions,
            "serve": f"python -m http.server -d {out} 8000  (then open http://localhost:8000)"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m unilab_jax.web", description=__doc__.split("\n")[0])
    parser.add_argument("--policy", required=True, help="the exported policy (python -m unilab_jax.export "
                        "--format onnx); its task config from PATH.json beside it, when present")
    parser.add_argument("--robot", default="go1", help=f"one of {', '.join(ROBOTS)} (default go1)")
    parser.add_argument("--out", required=True, help="folder to write the page into")
    parser.add_argument("--node_modules", default=REPO_NODE_MODULES,
                        help="where `npm ci` installed the page's packages (default: the repository's node_modules)")
    args = parser.parse_args(argv)
    try:
        result = build(args.policy, args.out, args.robot, args.node_modules)
    except WebError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
