"""``python -m unilab_jax.web``: the page runs the training task, its keys drive the robot, its view renders.

The pages are built here and driven in headless Chromium (Debian's ``chromium``; ``tests/web_driver.mjs``
through playwright-core from ``npm ci``), all jobs in one browser launch:

* parity: a policy exported by ``apps/export`` (a PPO actor with random weights and a normaliser) drives the
  page for 2 x 60 control steps under two commands; the Python task (with the same task overrides, read by
  the page from the policy's sidecar) replays the page's actions and must give the page's observation at
  every step, and onnxruntime on the page's observations the page's actions: the page is the training task.
* keys and the fast loop: the arrow keys set the command the policy sees, and ``?speed=max`` runs the
  simulation faster than real time.
* the view: a screenshot shows the robot's colours on the floor.
* walking (``policies/go1_walk.onnx``, skipped only while that file is absent): holding "up" for 10 simulated
  seconds walks the robot > 2 m forward without a fall; holding "left" / "right" turns it left / right.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
import types

import numpy as np
import pytest

import tasks
from unilab_jax.apps import export, web

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
WALK_POLICY = os.path.join(ROOT, "policies", "go1_walk.onnx")
DRIVER = os.path.join(ROOT, "tests", "web_driver.mjs")
CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
# The parity policy's sidecar: task overrides the page must apply (the model's gains, the action scale).
PARITY_OVERRIDES = {"kp": 30.0, "action_scale": 0.45}
# The Python task at evaluation, as the page runs it: no observation noise, no randomisation, home reset.
EVAL = {"domain_randomization": False, "noise_level": 0.0, "reset_xy": 0.0, "reset_yaw": 0.0, "reset_base_vel": 0.0}
COMMANDS = ([0.7, -0.2, 0.4], [-0.3, 0.25, -0.6])
STEPS = 60


def random_policy(path: str) -> None:
    """A PPO actor (normaliser, ELU MLP) with random weights, exported as ``apps/export`` exports a run."""
    import onnx

    r = np.random.default_rng(0)
    sizes = [48, 32, 12]
    w = {"obs_norm": types.SimpleNamespace(mean=r.normal(0, 0.1, 48), var=r.uniform(0.5, 2.0, 48)),
         "actor": [{"w": r.normal(0, 0.3 / np.sqrt(a), (a, b)), "b": r.normal(0, 0.05, b)}
                   for a, b in zip(sizes, sizes[1:])]}
    g, out = export.actor_graph("ppo", w, 48)
    onnx.save(export.to_onnx(g, out, 48, 12), path)


def run_driver(jobs: list[dict], tmp: str) -> list[dict]:
    if not os.path.isfile(CHROMIUM):
        pytest.fail(f"no Chromium at {CHROMIUM}: apt-get install chromium (.ci/run does)")
    path = os.path.join(tmp, "jobs.json")
    with open(path, "w") as f:
        json.dump(jobs, f)
    proc = subprocess.run(["node", DRIVER, path], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads(proc.stdout)
    for job, res in zip(jobs, results):
        assert not res["errors"], f"{job['name']}: {res['errors']}"
    return results


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    """{job name: values} of every page job, run in one Chromium."""
    tmp = str(tmp_path_factory.mktemp("web"))
    policy = os.path.join(tmp, "random.onnx")
    random_policy(policy)
    with open(os.path.join(tmp, "random.json"), "w") as f:
        json.dump({"task": "go1_joystick_flat", "task_overrides": PARITY_OVERRIDES}, f)
    pages = {"random": os.path.join(tmp, "random_page")}
    web.build(policy, pages["random"])
    segments = []
    for c in COMMANDS:
        segments += [{"eval": f"unilab.setCommand({c})"}, {"eval": f"unilab.advance({STEPS}, true)"}]
    jobs = [
        {"name": "parity", "dir": pages["random"], "query": "?speed=0&view=0",
         "actions": [{"eval": f"unilab.setCommand({COMMANDS[0]})"}, {"eval": "unilab.reset()"},
                     {"eval": "unilab.observation()"}, *segments]},
        {"name": "keys", "dir": pages["random"], "query": "?speed=max&view=0",
         "actions": [{"eval": "[performance.now(), unilab.state()]"}, {"down": "ArrowUp"}, {"down": "ArrowLeft"},
                     {"eval": "unilab.state().command"}, {"up": "ArrowLeft"}, {"down": "ArrowRight"},
                     {"eval": "unilab.state().command"}, {"up": "ArrowUp"}, {"up": "ArrowRight"},
                     {"down": "ArrowDown"}, {"eval": "unilab.state().command"}, {"up": "ArrowDown"},
                     {"wait": "unilab.state().time >= 4"}, {"eval": "[performance.now(), unilab.state()]"}]},
        {"name": "view", "dir": pages["random"], "query": "?speed=0",
         "actions": [{"eval": "unilab.advance(10)"}, {"eval": "new Promise(r => requestAnimationFrame(r))"},
                     {"screenshot": os.path.join(tmp, "view.png")}]},
    ]
    if os.path.exists(WALK_POLICY):
        pages["walk"] = os.path.join(tmp, "walk_page")
        web.build(WALK_POLICY, pages["walk"])
        jobs += [
            {"name": "walk", "dir": pages["walk"], "query": "?speed=0&view=0",
             "actions": [{"down": "ArrowUp"}, {"eval": "unilab.advance(500)"}, {"up": "ArrowUp"}]},
            {"name": "turn", "dir": pages["walk"], "query": "?speed=0&view=0",
             "actions": [{"down": "ArrowLeft"}, {"eval": "unilab.advance(150)"}, {"up": "ArrowLeft"},
                         {"eval": "unilab.reset()"},
                         {"down": "ArrowRight"}, {"eval": "unilab.advance(150)"}, {"up": "ArrowRight"}]},
        ]
    t = time.perf_counter()
    results = run_driver(jobs, tmp)
    print(f"browser jobs {[j['name'] for j in jobs]}: {time.perf_counter() - t:.1f} s")
    out = {job["name"]: res["values"] for job, res in zip(jobs, results)}
    out["tmp"], out["pages"] = tmp, pages
    return out


def test_page_runs_the_python_task(browser):
    """The page's observations are the Python task's, step by step, for the page's own actions (replayed), and
    its actions are onnxruntime's for its observations."""
    import onnxruntime as ort

    _, _, obs0, *segments = browser["parity"]
    task = tasks.make("go1_joystick_flat", 1, seed=0, overrides={**PARITY_OVERRIDES, **EVAL})
    session = ort.InferenceSession(os.path.join(browser["pages"]["random"], "policy.onnx"))
    try:
        obs = task.reset()[0][0]
        task.steps_until_next_cmd[:] = 10**9  # the command is the page's, never resampled
        # The reset observation: the page's command is set before its reset, the task's drawn at reset.
        np.testing.assert_allclose(obs0[:45], obs[:45], rtol=0, atol=1e-6)
        np.testing.assert_array_equal(obs0[45:], np.float32(COMMANDS[0]))
        obs[45:] = COMMANDS[0]
        worst = 0.0
        for command, (_, advanced) in zip(COMMANDS, zip(segments[::2], segments[1::2])):
            task.command[:] = command
            trace = advanced["trace"]
            assert len(trace) == STEPS
            for t, step in enumerate(trace):
                page_obs, page_act = np.float32(step["obs"]), np.float32(step["action"])
                err = np.abs(page_obs - obs).max()
                worst = max(worst, err)
                assert err < 1e-4, f"step {t}: |page obs - task obs| = {err}\n{page_obs}\n{obs}"
                ort_act = session.run(["action"], {"obs": page_obs[None]})[0][0]
                np.testing.assert_allclose(page_act, ort_act, rtol=0, atol=1e-5)
                out = task.step(page_act[None])
                assert not out.terminated[0] and not out.truncated[0]
                obs = out.obs[0]
            np.testing.assert_array_equal(np.float32(advanced["obs"][-3:]), np.float32(command))
            np.testing.assert_allclose(advanced["obs"], obs, rtol=0, atol=1e-4)
            assert advanced["state"]["falls"] == 0
        # The random policy moves the joints well away from the home pose: the comparison is not of a robot at rest.
        assert np.abs(np.float32(trace[-1]["obs"][9:21])).max() > 0.1
        print(f"parity: {2 * STEPS} steps, worst |page obs - task obs| {worst:.2e}")
    finally:
        task.close()


def test_keys_set_the_command_and_fast_mode_outruns_real_time(browser):
    (wall0, s0), up_left, up_right, down, (wall1, s1) = browser["keys"]
    keys = web.ROBOTS["go1"]
    assert up_left == [keys.forward, 0, keys.yaw_rate]
    assert up_right == [keys.forward, 0, -keys.yaw_rate]
    assert down == [-keys.forward, 0, 0]
    assert s1["command"] == [0, 0, 0]  # every key released
    sim, wall = s1["time"] - s0["time"], (wall1 - wall0) / 1000
    assert sim > 5 * wall, f"?speed=max ran {sim:.2f} simulated s in {wall:.2f} s of wall time"


def test_view_renders_the_robot(browser):
    from PIL import Image

    img = np.asarray(Image.open(os.path.join(browser["tmp"], "view.png")).convert("RGB")).astype(int)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    orange = (r > 170) & (g > 90) & (g < 170) & (b < 90)  # the legs' colour, 0xd9822b lit
    assert orange.sum() > 500, f"only {orange.sum()} leg-coloured pixels in the screenshot"
    assert img.std() > 20


walking = pytest.mark.skipif(not os.path.exists(WALK_POLICY), reason=f"{WALK_POLICY} is absent")


@walking
def test_holding_up_walks_forward(browser):
    (advanced,) = browser["walk"]
    state = advanced["state"]
    assert state["time"] == pytest.approx(10.0)
    assert state["falls"] == 0
    assert state["pos"][0] > 2.0, state


@walking
def test_turn_keys_turn_the_robot(browser):
    left, _, right = (v["state"] if "state" in v else v for v in browser["turn"])
    assert left["falls"] == 0 and right["falls"] == 0
    assert left["yaw"] > 0.5 and right["yaw"] < -0.5, (left, right)


def test_bad_input_exits_2(tmp_path):
    policy = tmp_path / "p.onnx"
    random_policy(str(policy))
    (tmp_path / "p.json").write_text(json.dumps({"task": "g1_walk_flat", "task_overrides": {}}))
    wrong = tmp_path / "wrong.onnx"
    import onnx
    from onnx import TensorProto, helper

    io = [helper.make_tensor_value_info(n, TensorProto.FLOAT, ["batch", 3]) for n in ("obs", "action")]
    onnx.save(helper.make_model(helper.make_graph([helper.make_node("Identity", ["obs"], ["action"])], "g",
                                                  io[:1], io[1:])), str(wrong))
    cases = [
        (["--policy", str(wrong), "--robot", "spot"], "--robot='spot'"),
        (["--policy", str(tmp_path / "none.onnx")], "no such file"),
        (["--policy", str(policy)], "trained on task 'g1_walk_flat'"),
        (["--policy", str(wrong)], "do not fit the task's obs_dim 48"),
    ]
    for args, message in cases:
        proc = subprocess.run([sys.executable, "-m", "unilab_jax.web", *args, "--out", str(tmp_path / "out")],
                              capture_output=True, text=True, cwd=ROOT)
        assert proc.returncode == 2, proc.stderr
        assert message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    shutil.rmtree(tmp_path / "out", ignore_errors=True)
