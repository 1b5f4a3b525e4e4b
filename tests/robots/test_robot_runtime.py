"""Robots as resources end to end: the pick-and-place experiment through robot servers, a robot server
killed mid-run (its worker waits, the others go on, the replay holds every transition once) and
restarted (the robot rejoins), bad inventories refused before anything starts."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest
from compile_options import fast_compile_env
from script_helpers import run_in_process

import tasks
from tasks.base import StepInterrupted
from unilab_jax.robots.client import query
from unilab_jax.robots.interface import RobotDisconnected, RobotEstopped, RobotFaulted
from unilab_jax.robots.inventory import InventoryError, LocalServer, discover, parse
from unilab_jax.runtime.pool import WorkerPool
from unilab_jax.runtime.worker import STEPS

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCRIPT = os.path.join(ROOT, "experiments", "sac_franka_pick.py")
FAST = ("--task=pick_place", "--speed=20", "--reset_s=0.1", "--cameras=none", "--dense_reward")
PROPRIO, KINDS = 13, 2


def _experiment(*args: str, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, SCRIPT, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                          env=fast_compile_env())


def test_sac_franka_pick_trains_on_two_sim_robots(tmp_path):
    logdir = tmp_path / "run"
    t = time.perf_counter()
    # 1,500 env steps (3,000 before; learning starts at 500): 62 learner calls logging losses and 68 rows with the
    # episodes' success rate (156 and 162 at 3,000); the test 17.1 -> 10.9 CPU-s, 16.6 -> 10.9 s (two runs each). The
    # robots unpaced (--speed=inf): the script alone 17.1 -> 13.2 s wall, 21.3 -> 19.3 CPU-s (one run each).
    out = _experiment("--robots=sim:franka_emika_panda,sim:universal_robots_ur5e", "--speed=inf",
                      "--total_steps=1500", f"--logdir={logdir}", timeout=240)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "franka_pick_place (franka" in out.stdout and "ur5e_pick_place (ur5e" in out.stdout
    rows = [json.loads(line) for line in open(logdir / "metrics.jsonl")]
    assert rows and rows[-1]["step"] >= 1500 and any("loss/critic_loss" in r or "loss/actor_loss" in r for r in rows)
    summary = json.load(open(logdir / "summary.json"))
    assert summary["env_steps"] >= 1500 and not summary["interrupted"] and "eval/return" in summary, summary
    assert np.isfinite(summary["eval/return"])
    assert summary["eval/episodes"] == 2 and 0.0 <= summary["eval/success_rate"] <= 1.0
    # Learning shows while the workers hold the robots: their episodes' success rate is logged.
    success = [r["episode/success_rate"] for r in rows if "episode/success_rate" in r]
    assert success and all(0.0 <= v <= 1.0 for v in success)
    assert os.listdir(logdir / "checkpoints")
    print(f"experiment: {time.perf_counter() - t:.1f} s, {summary['env_steps']} env steps")


@pytest.mark.parametrize("robots,message", [
    ("sim:mars_rover", "unknown simulated robot 'mars_rover'"),
    ("tcp://127.0.0.1", "bad robot address"),
    ("sim:franka_emika_panda,,", "no robots"),
    ("franka", "use sim:NAME"),
    ("/nonexistent/robots.toml", "robot inventory '/nonexistent/robots.toml'"),
])
def test_bad_robots_flag_exits_2_before_anything_starts(tmp_path, robots, message):
    # In this process (tests/script_helpers.py); tests/robots/test_rlpd_experiments.py checks a real process's exit.
    out = run_in_process(os.path.basename(SCRIPT), f"--robots={robots}", f"--logdir={tmp_path / 'x'}")
    assert out.returncode == 2, out.stderr[-2000:]
    assert message in out.stderr and "Traceback" not in out.stderr
    assert not (tmp_path / "x").exists()


def test_inventory_toml_and_discovery(tmp_path, serve):
    inv = tmp_path / "robots.toml"
    inv.write_text('[[robot]]\nsim = "universal_robots_ur5e"\n[[robot]]\naddress = "tcp://127.0.0.1:5999"\n')
    assert [str(e) for e in parse(str(inv))] == ["sim:universal_robots_ur5e", "tcp://127.0.0.1:5999"]
    franka = serve("--robot=franka", *FAST)
    peg = serve("--robot=ur5e", "--task=peg_insertion", "--speed=20", "--cameras=none")
    (found,) = discover([franka.address], task="pick_place")
    assert found.spec.kind == "franka" and found.health.state == "ok" and found.health.owner == ""
    with pytest.raises(InventoryError, match="this run needs 'pick_place'"):
        discover([franka.address, peg.address], task="pick_place")
    with pytest.raises(InventoryError, match="no robot server answers at tcp://127.0.0.1:1"):
        discover(["tcp://127.0.0.1:1"], timeout_s=0.3)


def _fail_once(robot, method: str, error: Exception | None = None) -> None:
    real = getattr(robot, method)

    def fail(*args):
        setattr(robot, method, real)
        raise error or RobotFaulted("injected")

    setattr(robot, method, fail)


def test_a_failed_step_is_interrupted_and_a_failed_reset_costs_no_transition():
    task = tasks.make("robot_pick_place", 2, seed=0, overrides={"episode_length": 2})
    try:
        obs, _ = task.reset()
        calls = []
        task.keepalive = lambda: calls.append(1)
        zero = np.zeros((2, 7), np.float32)
        task.step(zero)
        _fail_once(task.robots[1], "step")
        with pytest.raises(StepInterrupted, match="RobotFaulted: injected") as e:
            task.step(zero)
        assert (e.value.critic_obs[:, -1] == 0).all() and (task.steps == 0).all()  # every env restarted
        assert task.losses == task.rejoins == 1 and calls
        task.step(zero)
        _fail_once(task.robots[0], "reset")  # lost while resetting after the episode's last step
        out = task.step(zero)
        assert out.truncated.all() and (out.critic_obs[:, -1] == 0).all() and (out.next_critic_obs[:, -1] == 1).all()
        assert task.losses == task.rejoins == 2
    finally:
        task.close()


def test_a_protective_stop_ends_only_its_robot_s_episode_while_evaluating():
    """``stop_ends_episode`` (run_episodes sets it): a protective stop truncates that robot's episode (no success,
    reward 0, marked in ``extras``) and the others go on; a stop beside a lost robot, an operator's estop, or any stop
    in training (the flag unset) interrupts the step for every env."""
    protective = RobotEstopped("emergency stop engaged (protective stop: contact force 1285 N > 1000): call reset()")
    task = tasks.make("robot_pick_place", 2, seed=0, overrides={"episode_length": 5})
    try:
        task.reset()
        zero = np.zeros((2, 7), np.float32)
        task.stop_ends_episode = True
        task.step(zero)
        _fail_once(task.robots[1], "step", protective)
        out = task.step(zero)
        assert out.extras["protective_stop"].tolist() == [False, True] and out.truncated.tolist() == [False, True]
        assert out.reward[1] == 0.0 and not out.terminated.any() and task.steps.tolist() == [2, 0]
        for errors in ({0: protective, 1: RobotDisconnected("lost")},
                       {0: RobotEstopped("emergency stop engaged: call clear_estop() or reset()")}):
            for i, error in errors.items():
                _fail_once(task.robots[i], "step", error)
            with pytest.raises(StepInterrupted):
                task.step(zero)
        task.stop_ends_episode = False
        _fail_once(task.robots[0], "step", protective)
        with pytest.raises(StepInterrupted, match="protective stop"):
            task.step(zero)
    finally:
        task.close()


def _wait(cond, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.05)


def test_killed_robot_stops_its_worker_only_and_rejoins_when_restarted(serve):
    """Two robots, two workers; one server is SIGKILLed mid-episode: its worker waits (heartbeating past
    the pool's 3 s hang timeout, not respawned) while the other goes on; a server restarted on the same
    port is claimed again and its worker produces again. Each worker's replay rows form one unbroken
    chain of transitions (next_obs of a row is the obs of the next, except across episode ends and the
    one interrupted step): nothing lost, nothing twice."""
    servers = [serve("--robot=franka", *FAST), serve("--robot=ur5e", *FAST)]
    overrides = {"robots": tuple(s.address for s in servers), "timeout_s": 0.5, "retry_s": 0.2}
    pool = WorkerPool("robot_pick_place", overrides, num_workers=2, envs_per_worker=1, algo_module="robot_toy_algo",
                      weight_template={"w": np.zeros(1, np.float32)}, replay_capacity=100_000, heartbeat_timeout=3.0,
                      max_restarts=0)
    with pool:
        pool.start()
        pool.publish({"w": np.zeros(1, np.float32)}, 1)
        words = pool._ctl["worker"]
        _wait(lambda: words[:, STEPS].min() >= 100, 60, "100 steps per worker")
        rows0 = {w: pool.buffer._data[w]["obs"][0] for w in range(2)}
        slot_of = {w: int(np.argmax(rows0[w][PROPRIO + KINDS:])) for w in range(2)}
        assert sorted(slot_of.values()) == [0, 1]  # each worker claimed its own robot
        victim = next(w for w in range(2) if slot_of[w] == 1)
        other = 1 - victim
        servers[1].kill()
        time.sleep(1.5)  # the lost step times out (0.5 s + its period)
        frozen, before = int(words[victim, STEPS]), int(words[other, STEPS])
        time.sleep(4.0)
        assert int(words[victim, STEPS]) == frozen, "the worker of the killed robot kept producing"
        assert int(words[other, STEPS]) > before + 100, "the other robot's worker stopped"
        st = pool.stats()
        assert st["worker_restarts"] == 0 and st["workers_waiting"] == 1  # waiting for its robot, it heartbeats
        servers.append(serve("--robot=ur5e", f"--port={servers[1].port}", *FAST))
        _wait(lambda: int(words[victim, STEPS]) >= frozen + 100, 60, "the restarted robot to rejoin")
        pool.set_step_limit(0)
        time.sleep(0.5)
        st = pool.stats()
        # Counted once the step gave up; a protective stop of a live robot (random actions on a loaded machine)
        # interrupts a step too, and its server counts it.
        stops = {slot: sum(query(s.address)[1].limit_hits[k] for k in ("pose", "tcp_speed", "force"))
                 for slot, s in ((0, servers[0]), (1, servers[2]))}
        assert st["interrupted_steps"] == 1 + sum(stops.values()) and st["workers_waiting"] == 0
        for w in range(2):
            n = pool.buffer.count(w)
            assert n == int(words[w, STEPS])
            data = {k: pool.buffer._data[w][k][:n] for k in ("obs", "next_obs", "critic_obs", "terminated",
                                                             "truncated")}
            assert (np.argmax(data["obs"][:, PROPRIO + KINDS:], axis=1) == slot_of[w]).all()
            ended = data["terminated"] | data["truncated"]
            linked = (data["next_obs"][:-1] == data["obs"][1:]).all(axis=1)
            breaks = np.flatnonzero(~linked & ~ended[:-1])
            # One break where the step was given up (and one per protective stop of the worker's robot); none when
            # that step was the first of an episode (the row before it ended, so the chain restarts there anyway).
            assert len(breaks) <= (1 if w == victim else 0) + stops[slot_of[w]], breaks
            # The row after the break starts a new episode (episode time 0 in the critic observation).
            assert all(data["critic_obs"][b + 1, -1] == 0.0 for b in breaks)


def test_run_goes_on_when_a_robot_server_dies(tmp_path, serve):
    """The experiment on two running servers; one is killed once training is under way: the run reaches
    its step budget on the other robot, saves its checkpoint and exits 0 (evaluating on one robot)."""
    servers = [serve("--robot=franka", *FAST), serve("--robot=ur5e", *FAST)]
    logdir = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, SCRIPT, f"--robots={servers[0].address},{servers[1].address}",
                             "--total_steps=1500", "--eval_envs=1", "--task_config=timeout_s=0.5",
                             f"--logdir={logdir}"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=fast_compile_env())
    try:
        metrics = logdir / "metrics.jsonl"
        _wait(lambda: metrics.exists() and any(json.loads(line)["step"] >= 500 for line in open(metrics)), 120,
              "500 env steps")
        servers[1].kill()
        _, err = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 0, err[-3000:]
    summary = json.load(open(logdir / "summary.json"))
    assert summary["env_steps"] >= 1500 and not summary["interrupted"]
    assert os.listdir(logdir / "checkpoints")
    rows = [json.loads(line) for line in open(logdir / "metrics.jsonl")]
    assert any(r.get("perf/workers_waiting") == 1 for r in rows)  # the worker of the dead robot, logged


def test_evaluation_goes_on_with_the_robots_that_answer(serve):
    """A robot gone for good: a task asking for every robot fails after connect_timeout_s, one with
    ``min_envs`` (the end-of-run evaluation of the robot experiments) runs on the robots left."""
    alive, dead = serve("--robot=franka", *FAST), serve("--robot=ur5e", *FAST)
    dead.kill()
    robots = (alive.address, dead.address)
    quick = {"robots": robots, "connect_timeout_s": 1.0, "timeout_s": 0.3, "retry_s": 0.2}
    with pytest.raises(RuntimeError, match="2 robots wanted, 1 free"):
        tasks.make("robot_pick_place", 2, overrides=quick)
    task = tasks.make("robot_pick_place", 2, overrides={**quick, "min_envs": 1})
    try:
        assert task.num_envs == 1 and task.slots == [0]
        obs, _ = task.reset()
        out = task.step(np.zeros((1, task.spec.action_dim), np.float32))
        assert obs.shape == out.obs.shape == (1, task.spec.obs_dim) and task.spec.success_on_termination
    finally:
        task.close()
    with pytest.raises(RuntimeError, match="2 robots wanted, 0 free"):  # min_envs is a floor
        tasks.make("robot_pick_place", 2, overrides={**quick, "robots": (dead.address, dead.address), "min_envs": 1})


def test_a_local_server_that_fails_to_start_says_why():
    with pytest.raises(InventoryError, match=r"failed to start \(exit 2\): error: unknown task 'no_such_task'"):
        LocalServer("franka", "no_such_task", 20.0)


_LAUNCHER = """
import time
from unilab_jax.robots.inventory import LocalServer
server = LocalServer("franka", "pick_place", 20.0)
print(server.proc.pid, flush=True)
time.sleep(600)
"""


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as f:
            return any(line.split()[1] == "Z" for line in f if line.startswith("State:"))
    except FileNotFoundError:
        return True


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads /proc")
def test_local_servers_stop_when_their_launcher_is_killed():
    """SIGKILL runs no clean-up in the launcher: the server notices it is orphaned and exits by itself."""
    launcher = subprocess.Popen([sys.executable, "-c", _LAUNCHER], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        server_pid = int(launcher.stdout.readline())
        assert not _gone(server_pid)
        launcher.kill()
        launcher.wait(10)
        deadline = time.monotonic() + 10.0
        while not _gone(server_pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _gone(server_pid), "the robot server outlived its killed launcher"
    finally:
        launcher.kill()
        launcher.stdout.close()
