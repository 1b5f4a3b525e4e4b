"""The trainer's background evaluator: slow evaluations do not queue up behind a fast training loop."""

import os
import signal
import threading
import time
from concurrent.futures.process import BrokenProcessPool

import pytest

from unilab_jax.training.evaluation import AsyncEvaluator


class _SlowTrainer:
    """Stands in for the Trainer: ``evaluate`` blocks until released and records what it evaluated."""

    def __init__(self):
        self.t0 = time.time()
        self.release = threading.Event()
        self.evaluated: list[int] = []
        self.logged: list[tuple[int, dict]] = []
        self.logger = self

    def evaluate(self, weights, seed, stop=None):
        self.release.wait(timeout=10)
        self.evaluated.append(weights["step"])
        return {"eval/return": float(weights["step"])}

    def log(self, step, scalars):
        self.logged.append((step, scalars))


def _submit(ev, step):
    ev.submit({"step": step}, {"updates": step, "env_steps": step}, wall_s=float(step))


def test_a_newer_snapshot_replaces_the_waiting_one():
    tr = _SlowTrainer()
    ev = AsyncEvaluator(tr)
    for step in range(1, 6):  # 1 runs (blocked); 2, 3, 4 each replaced by the next; 5 waits
        _submit(ev, step)
        time.sleep(0.05)
    assert ev.skipped == 3
    tr.release.set()
    last = ev.close()
    assert tr.evaluated == [1, 5]
    assert last["eval/return"] == 5.0 and last["eval/skipped"] == 3.0
    assert [s for s, _ in tr.logged] == [1, 5]


def test_close_with_cancel_drops_the_waiting_evaluation():
    tr = _SlowTrainer()
    ev = AsyncEvaluator(tr)
    _submit(ev, 1)
    time.sleep(0.05)
    _submit(ev, 2)
    threading.Timer(0.2, tr.release.set).start()
    t0 = time.time()
    last = ev.close(cancel=True)
    assert tr.evaluated == [1] and last["eval/return"] == 1.0
    assert time.time() - t0 < 5


def test_close_without_evaluations_returns_nothing():
    assert AsyncEvaluator(_SlowTrainer()).close() == {}


class _FailingTrainer(_SlowTrainer):
    """Step 2's evaluation fails with ``error`` (robots that make protective stops past the restarts; the evaluation
    process dying under it, what the executor raises then)."""

    def __init__(self, error):
        super().__init__()
        self.error = error

    def evaluate(self, weights, seed, stop=None):
        if weights["step"] == 2:
            raise self.error
        return super().evaluate(weights, seed, stop)


def _interrupted():
    from tasks.base import StepInterrupted

    return StepInterrupted("tcp://robot: RobotEstopped: protective stop", None, None)


@pytest.mark.parametrize("error, counter", [(_interrupted, "interrupted"),
                                            (lambda: BrokenProcessPool("terminated abruptly"), "lost")])
def test_an_evaluation_that_fails_is_dropped_and_ends_no_run(error, counter):
    tr = _FailingTrainer(error())
    tr.release.set()
    ev = AsyncEvaluator(tr)
    _submit(ev, 1)
    deadline = time.time() + 10
    while not tr.logged and time.time() < deadline:  # step 1 done before step 2 is submitted (not replaced)
        time.sleep(0.01)
    _submit(ev, 2)
    last = ev.close()  # no exception: the newest finished evaluation stands
    assert getattr(ev, counter) == 1 and last["eval/return"] == 1.0
    assert [s for s, _ in tr.logged] == [1]  # nothing logged for the dropped one


def test_the_evaluation_process_outlives_a_signal_to_the_process_group():
    """`timeout` and Ctrl-C signal the whole process group: the trainer stops the child through its stop event;
    a child that died of the signal broke the pool and the run ended without its summary (issue 37's runs)."""
    from unilab_jax.training.evaluation import EvaluationProcess, _child_ready

    process = EvaluationProcess()
    try:
        assert process._pool.submit(_child_ready).result(timeout=60) is True  # the child is up, its initializer run
        (pid,) = list(process._pool._processes)
        os.kill(pid, signal.SIGTERM)
        os.kill(pid, signal.SIGINT)
        time.sleep(0.3)
        assert process._pool.submit(_child_ready).result(timeout=60) is True
    finally:
        process.close()


def test_an_evaluation_process_gives_the_thread_s_result_and_stops_when_asked(tmp_path):
    import numpy as np
    import pytest

    from tasks.base import StepInterrupted
    from unilab_jax import algos
    from unilab_jax.config import apply_overrides
    from unilab_jax.runtime import StopRequested
    from unilab_jax.training.evaluation import EvaluationProcess, evaluate_policy
    from unilab_jax.training.trainer import RunConfig, Trainer

    module = algos.get("ppo")
    run = RunConfig(algo="ppo", task="cartpole_balance", logdir=str(tmp_path), eval_envs=3)
    trainer = Trainer(run, module, apply_overrides(module.Config(), {"actor_hidden": (8,), "critic_hidden": (8,)}), {})
    weights = trainer._numpy_weights(trainer.learner.init(trainer.xp.random.key(0)))
    job = trainer.evaluation_job(weights, seed=4)
    process = EvaluationProcess()
    try:
        # the same deterministic episodes in the child as in this process
        assert process.evaluate(job) == evaluate_policy(**job) == trainer.evaluate(weights, seed=4)
        stop = threading.Event()
        stop.set()
        with pytest.raises(StopRequested):
            process.evaluate(job, stop)
    finally:
        process.close()
    # a robot task's interruption reaches the trainer's evaluator from the child whole
    e = StepInterrupted("tcp://robot: lost", np.ones(2), np.zeros(3))
    import pickle

    back = pickle.loads(pickle.dumps(e))
    assert str(back) == "tcp://robot: lost" and back.obs.tolist() == [1, 1] and back.critic_obs.shape == (3,)


def test_a_run_whose_last_evaluation_was_dropped_says_so_in_its_summary(tmp_path, monkeypatch):
    from tasks.base import StepInterrupted
    from unilab_jax import algos
    from unilab_jax.config import apply_overrides
    from unilab_jax.training.trainer import RunConfig, Trainer

    def lost(self, weights, seed, stop=None):
        raise StepInterrupted("tcp://robot: RobotDisconnected: lost", None, None)

    monkeypatch.setattr(Trainer, "evaluate", lost)
    module = algos.get("ppo")
    config = apply_overrides(module.Config(), {"actor_hidden": (8,), "critic_hidden": (8,), "horizon": 8})
    run = RunConfig(algo="ppo", task="cartpole_balance", logdir=str(tmp_path), num_workers=1, envs_per_worker=4,
                    total_steps=64, serial=True, eval_envs=2, eval_process="off")
    summary = Trainer(run, module, config, {}).train()
    assert summary["eval/dropped"] == 1 and "eval/return" not in summary and not summary["interrupted"]
