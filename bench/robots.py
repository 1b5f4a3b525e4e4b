"""Robot-server numbers: step latency over the wire (idle and under a flood), camera render time per frame,
scripted-expert success.

    MENAGERIE_ROOT=../shared/robots python bench/robots.py [--episodes 50] [--out bench/results/robots.json]
    python bench/robots.py --parts render --sizes 64 128 --out bench/results/h100/render_cameras.json   # GPU machine

* ``step_ms``: wall time of ``RobotClient.step`` against a ``python -m unilab_jax.robots.serve`` process
  (Franka pick-and-place, no cameras) at speed 1 and 20 (control period 100 ms and 5 ms).
* ``flood``: the owner's median step latency on a keyed server (unpaced Franka, loopback, one thread) idle, under a
  flood and idle again: ``bench/flood_clients.py`` at nice 10, 200 admitted sockets asking ``health`` four at a
  time as fast as answered plus a connection with an unknown key every 5 ms; a flooded window counts when the
  server dropped >= 300 requests during it (on a busy machine the low-priority flood may pause). With the server's
  ``rate_limited`` and ``denied`` counters and the flood's own counts.
* ``render``: in a fresh interpreter with ``MUJOCO_GL`` as set, else the first working backend: per (task, arm,
  camera geometry, size) the milliseconds of one ``mujoco.Renderer`` frame of each camera (``front``, ``wrist``;
  ``update_scene`` + ``render``, 20 frames after one warm-up) and of one control step with both cameras (physics,
  IK and both frames: ``SimRobot.step`` unpaced), with the GL renderer's name (NVIDIA's EGL or Mesa's llvmpipe)
  and the machine (CPU, cores, GPUs, load). Skipped when no backend renders.
* ``experts``: success rate of each scripted expert over ``--episodes`` episodes, in-process, unpaced.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
if REPO not in sys.path:  # bench.machine, when run as a script
    sys.path.insert(0, REPO)

from bench import flood_clients  # noqa: E402
from bench.machine import cpu_model, write_json  # noqa: E402
from unilab_jax.robots import keys  # noqa: E402
from unilab_jax.robots.client import RobotClient  # noqa: E402
from unilab_jax.robots.experts import PAIRS, evaluate_expert  # noqa: E402
from unilab_jax.robots.gl import find_gl_backend  # noqa: E402

HOLD = np.array([0.0, 0, 0, 0, 0, 0, -1.0], dtype=np.float32)
PARTS = ("step", "flood", "render", "experts")
FLOOD_WINDOWS, FLOOD_DROPS = 5, 300  # flooded windows of 80 steps; drops that show the flood was on all along

_RENDER = """
import json, sys, time
import numpy as np
from unilab_jax.robots.sim import SimConfig, SimRobot
sizes, frames = json.loads(sys.argv[1]), 20
rows, gl = [], None
for task, arm in (("peg_insertion", "franka"), ("pick_place", "franka"), ("pick_place", "ur5e")):
    for geometry in ("visual", "collision"):
        for size in sizes:
            robot = SimRobot(SimConfig(arm=arm, task=task, cameras=("front", "wrist"), image_size=size,
                                       camera_geometry=geometry, speed=float("inf"), reset_seconds=0.0))
            robot.reset(seed=0)
            if gl is None:
                try:
                    from OpenGL import GL
                    gl = GL.glGetString(GL.GL_RENDERER).decode()
                except Exception as e:
                    gl = f"unknown ({type(e).__name__})"
            row = {"task": task, "arm": arm, "geometry": geometry, "size": size}
            r = robot._renderer
            for cam in ("front", "wrist"):
                r.update_scene(robot.data, camera=cam, scene_option=robot._scene_option); r.render()
                t = time.perf_counter()
                for _ in range(frames):
                    r.update_scene(robot.data, camera=cam, scene_option=robot._scene_option); r.render()
                row[f"{cam}_ms"] = (time.perf_counter() - t) / frames * 1e3
            hold = np.array([0, 0, 0, 0, 0, 0, 1 if task == "peg_insertion" else -1], np.float32)
            t = time.perf_counter()
            for _ in range(frames):
                robot.step(hold)
            row["step_with_cameras_ms"] = (time.perf_counter() - t) / frames * 1e3
            rows.append(row)
            robot.close()
print(json.dumps({"gl_renderer": gl, "rows": rows}))
"""


def machine() -> dict:
    import mujoco

    cpu = cpu_model()
    try:
        gpus = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=30).stdout.split("\n")
    except (OSError, subprocess.TimeoutExpired):
        gpus = []
    return {"hostname": platform.node(), "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "cpu_model": cpu,
            "cpu_count": os.cpu_count(), "gpus": [g for g in gpus if g], "loadavg": list(os.getloadavg()),
            "python": platform.python_version(), "mujoco": mujoco.__version__}


def step_latency(speed: float, steps: int) -> dict:
    cmd = [sys.executable, "-m", "unilab_jax.robots.serve", "--robot=franka", "--task=pick_place", "--port=0",
           f"--speed={speed}", "--cameras=none", "--reset_s=0.2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        address = proc.stdout.readline().split(" on ")[1].strip()
        with RobotClient(address, timeout_s=5.0) as robot:
            robot.reset(seed=0)
            times = []
            for _ in range(steps):
                t = time.perf_counter()
                result = robot.step(HOLD)
                times.append((time.perf_counter() - t) * 1e3)
                if result.terminated or result.truncated:
                    robot.reset()
            health = robot.health()
    finally:
        proc.terminate()
        proc.wait(10)
    t = np.array(times)
    return {"speed": speed, "period_ms": 100.0 / speed, "mean": t.mean(), "median": float(np.median(t)),
            "min": t.min(), "max": t.max(), "late_actions": health.late_actions, "overruns": health.overruns}


def _median_step_ms(robot: RobotClient, n: int) -> float:
    times = []
    for i in range(n):
        t = time.perf_counter()
        step = robot.step(HOLD if i % 2 else -HOLD)
        times.append(time.perf_counter() - t)
        if step.terminated or step.truncated:
            robot.reset()
    return float(np.median(times)) * 1e3


def flood_latency(sockets: int = 200) -> dict:
    with tempfile.TemporaryDirectory() as d:
        keys.new("server", d)
        keys.new("owner", os.path.join(d, "allow"))
        keys.new("other", os.path.join(d, "allow"))
        server_key = keys.load_public(os.path.join(d, "server.key"))
        public, secret = keys.load_pair(os.path.join(d, "allow", "owner.key_secret"))
        cmd = [sys.executable, "-m", "unilab_jax.robots.serve", "--robot=franka", "--task=pick_place", "--port=0",
               "--speed=inf", "--reset_s=0", "--cameras=none", f"--key={os.path.join(d, 'server.key_secret')}",
               f"--allow={os.path.join(d, 'allow')}"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                env={**os.environ, "OMP_NUM_THREADS": "1"})
        try:
            address = proc.stdout.readline().split(" on ")[1].strip()
            with RobotClient(address, keys=keys.ClientKeys(public, secret, server_key), timeout_s=5.0,
                             lease_s=600, heartbeat_s=0) as robot:
                robot.reset(seed=0)
                _median_step_ms(robot, 20)
                idle = _median_step_ms(robot, 150)
                flood = flood_clients.launch(address, FLOOD_WINDOWS * 1.5, sockets, server_key.decode(),
                                             os.path.join(d, "allow", "other.key_secret"))
                windows = []
                try:
                    time.sleep(0.5)  # its sockets connect
                    for _ in range(FLOOD_WINDOWS):
                        before = robot.health().limit_hits["rate_limited"]
                        ms = _median_step_ms(robot, 80)
                        windows.append({"median_ms": ms, "dropped": robot.health().limit_hits["rate_limited"] - before})
                finally:
                    flood_out = flood.communicate(timeout=60)[0]
                idle_after = _median_step_ms(robot, 150)
                hits = robot.health().limit_hits
        finally:
            proc.terminate()
            proc.wait(10)
    flooded = [w["median_ms"] for w in windows if w["dropped"] >= FLOOD_DROPS]
    return {"sockets": sockets, "idle_ms": idle, "idle_after_ms": idle_after, "windows": windows,
            "flooded_ms": float(np.median(flooded)) if flooded else None,
            "flooded_over_idle": float(np.median(flooded)) / max(idle, idle_after) if flooded else None,
            "rate_limited": hits["rate_limited"], "denied": hits["denied"],
            "flood": flood_clients.counts(flood_out)}


def render_times(sizes: list[int]) -> dict:
    backend = os.environ.get("MUJOCO_GL")
    if backend is None:
        backend, reasons = find_gl_backend()
        if backend is None:
            return {"skipped": reasons}
    out = subprocess.run([sys.executable, "-c", _RENDER, json.dumps(sizes)], env={**os.environ, "MUJOCO_GL": backend},
                         capture_output=True, text=True, timeout=1200)
    if out.returncode != 0:
        return {"backend": backend, "failed": out.stderr.strip().splitlines()[-3:]}
    return {"backend": backend, **json.loads(out.stdout.strip().splitlines()[-1])}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--parts", nargs="+", choices=PARTS, default=list(PARTS))
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 128], help="camera image sizes (render)")
    p.add_argument("--out", default="bench/results/robots.json")
    args = p.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    result = {"machine": machine(), "commit": commit}
    if "step" in args.parts:
        result["step_ms"] = [step_latency(1.0, 20), step_latency(20.0, 90)]
    if "flood" in args.parts:
        result["flood"] = flood_latency()
        f = result["flood"]
        print(f"owner step: idle {f['idle_ms']:.2f} / {f['idle_after_ms']:.2f} ms, flooded {f['flooded_ms']} ms "
              f"({len(f['windows'])} windows); server dropped {f['rate_limited']}, denied {f['denied']}", flush=True)
    if "render" in args.parts:
        result["render"] = render_times(args.sizes)
        for row in result["render"].get("rows", []):
            print(f"{row['task']:>13} {row['arm']:>6} {row['geometry']:>9} {row['size']:>3} px: front "
                  f"{row['front_ms']:6.2f} ms, wrist {row['wrist_ms']:6.2f} ms, step with both "
                  f"{row['step_with_cameras_ms']:6.2f} ms", flush=True)
    if "experts" in args.parts:
        result["experts"] = [evaluate_expert(task, arm, args.episodes) for task, arm in PAIRS]
    print(json.dumps(result, indent=1, default=float))
    write_json(args.out, result)


if __name__ == "__main__":
    main()
