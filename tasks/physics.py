"""Batched CPU MuJoCo stepping shared by the tasks (numpy + mujoco only; no shim, no jax).

``BatchedSim`` owns the physics state of ``num_envs`` environments as numpy arrays
(``qpos [M, nq]``, ``qvel [M, nv]``, ``sensordata [M, nsensordata]``, ...) and advances all of them
one control step (``nsub`` physics substeps under a zero-order-hold control) per call. Two engines:

* ``"rollout"``: one ``mujoco.rollout`` call per control step. The substep loop runs in C for the
  whole batch; there is no per-env Python work at all. ``mujoco.rollout`` does not return
  ``qacc_warmstart``, so the solver's warm start for the first substep of the next control step is
  rebuilt from the last substep's velocity change (``(qvel[n] - qvel[n-1]) / dt``, the acceleration
  the Euler integrator applied) and passed back as ``initial_warmstart``. MuJoCo's own divergence
  guard (``mj_checkPos/Vel/Acc``) resets an unstable env inside the rollout, which also zeroes its
  time; a time that does not match ``t0 + nsub * timestep`` therefore flags that env as unstable.
* ``"step"``: one ``mujoco.mj_step(model, data, nsub)`` per env and control step (a Python loop of
  ``num_envs`` C calls); warnings come from ``data.warning`` counters.

Both take per-env models (``models=[...]``, same size signature) for domain randomisation.

Measured with ``MENAGERIE_ROOT=... taskset -c 1 python -m tasks.physics [num_envs]``
(go1_joystick_flat with its default domain randomisation, i.e. per-env models; feet-only contacts,
5 substeps, uniform random actions with auto-resets; one single-threaded process; env steps per
CPU-second of that process, best of 3 interleaved; 2-core dev VM under a load of ~4-5):

=========  ========  ==========================  ===========================
engine     num_envs  physics only (env steps/s)  whole task.step (env steps/s)
=========  ========  ==========================  ===========================
rollout    256       12.8k                       11.7k
step       256        9.8k                        8.9k
rollout    64        11.8k                       10.3k
step       64         9.5k                        7.9k
=========  ========  ==========================  ===========================

so ``"rollout"`` is the default (~30% faster: no per-env Python calls, state gathered by the C
loop). The engines agree to ~1e-13 in qpos over 100 control steps (the rebuilt warm start reproduces
``mj_step``'s; with a zero warm start they diverge, which the tests catch).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import mujoco
import mujoco.rollout
import numpy as np

ENGINES = ("rollout", "step")
_log = logging.getLogger(__name__)
_SENSOR_OFF = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
# Warnings that mean the simulation diverged (MuJoCo resets the data when they fire).
_BAD_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADCTRL,
)


def _route_mujoco_warnings() -> None:
    """Sends MuJoCo's text warnings to ``logging`` instead of stdout + ``MUJOCO_LOG.TXT`` in the cwd.

    Leaves a handler someone else installed alone. The per-env divergence signal does not depend on
    this (it comes from ``data.warning`` counters or the reset-time check).
    """
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(lambda msg: _log.warning("MuJoCo: %s", msg))


class BatchedSim:
    """``num_envs`` MuJoCo environments stepped together; state lives in batched numpy arrays.

    Attributes (views are refreshed by ``step`` / ``set_state``; treat them as read-only):
      qpos [M, nq], qvel [M, nv], act [M, na], time [M], sensordata [M, nsensordata] (float64).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        num_envs: int,
        nsub: int,
        engine: str = "rollout",
        models: Sequence[mujoco.MjModel] | None = None,
        sensors_every_substep: bool = False,
    ):
        if engine not in ENGINES:
            raise ValueError(f"unknown physics engine {engine!r}; choose one of {ENGINES}")
        if models is not None and len(models) != num_envs:
            raise ValueError(f"need one model per env: got {len(models)} for {num_envs} envs")
        self.model = model
        self.models = list(models) if models is not None else None
        self.num_envs = int(num_envs)
        self.nsub = int(nsub)
        self.engine = engine
        _route_mujoco_warnings()
        m = model
        self.nq, self.nv, self.nu, self.na, self.ns = m.nq, m.nv, m.nu, m.na, m.nsensordata
        self.nstate = mujoco.mj_stateSize(m, _FULL)
        M = self.num_envs
        # Full-physics state [time, qpos, qvel, act, ...] per env; the named arrays are views.
        self.state = np.zeros((M, self.nstate))
        self.time = self.state[:, 0]
        self.qpos = self.state[:, 1 : 1 + self.nq]
        self.qvel = self.state[:, 1 + self.nq : 1 + self.nq + self.nv]
        self.act = self.state[:, 1 + self.nq + self.nv : 1 + self.nq + self.nv + self.na]
        self.sensordata = np.zeros((M, self.ns))
        self.warmstart = np.zeros((M, self.nv))
        self._dt = np.array([mm.opt.timestep for mm in self.models])[:, None] if self.models else None
        # One scratch MjData for set_state/forward (and rollout's single thread); per-env datas for
        # the step engine.
        self._scratch = mujoco.MjData(m)
        self._view: mujoco.MjData | None = None  # render-only data of ``scene``, made on first use
        self._data_models = self.models if self.models is not None else [m] * M
        # Sensors are only read after the last substep, so the other substeps can run with
        # mjDSBL_SENSOR set (same dynamics, no sensor/rnePostConstraint work; the flag is toggled on
        # the models). For the rollout engine that costs a second rollout call per control step,
        # and with per-env (randomised) models each call pays ~10 us per env to bring that env's
        # model into cache: measured on Go1 with DR, one call with sensors on every substep was
        # faster (11.2k vs 9.7k env steps/s), while with one shared model skipping won (14.0k vs
        # 12.3k). So skipping is used where it measured faster: the step engine, or one shared model.
        self._split = (
            self.nsub > 1 and not sensors_every_substep and self.ns > 0
            and (engine == "step" or self.models is None)
        )
        self._unique_models = list({id(mm): mm for mm in self._data_models}.values())
        phases = [(False, self.nsub - 1), (True, 1)] if self._split else [(True, self.nsub)]
        if engine == "step":
            self.datas = [mujoco.MjData(mm) for mm in self._data_models]
        else:
            self.datas = []
            self._rollout = mujoco.rollout.Rollout(nthread=0)
        # Per phase: (sensors on, nstep, ctrl [M, nstep, nu], state out [M, nstep, nstate], sensors out).
        self._phases = [
            (on, n, np.zeros((M, n, self.nu)), np.zeros((M, n, self.nstate)), np.zeros((M, n, self.ns)))
            for on, n in phases
        ]
        # Ground-truth layout check: our views must match mj_getState's packing.
        d = self._scratch
        mujoco.mj_resetData(m, d)
        probe = np.empty(self.nstate)
        mujoco.mj_getState(m, d, probe, _FULL)
        if not np.allclose(probe[1 : 1 + self.nq], d.qpos):
            raise RuntimeError("unexpected mjSTATE_FULLPHYSICS layout")
        self.reset_all_to(np.tile(m.qpos0, (M, 1)), np.zeros((M, self.nv)))

    # ----------------------------------------------------------------------------------------------
    def set_state(self, idx: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, ctrl: np.ndarray | None = None):
        """Sets envs ``idx`` to (qpos, qvel) at time 0 and recomputes their sensors (mj_forward).

        Per-env work here is one mj_forward per *reset* env, not per step.
        """
        idx = np.asarray(idx, dtype=np.int64).reshape(-1)
        if idx.size == 0:
            return
        qpos = np.asarray(qpos, dtype=np.float64).reshape(idx.size, self.nq)
        qvel = np.asarray(qvel, dtype=np.float64).reshape(idx.size, self.nv)
        for k, i in enumerate(idx):
            mm = self._data_models[i]
            d = self.datas[i] if self.engine == "step" else self._scratch
            mujoco.mj_resetData(mm, d)  # also zeroes time, warm start and warning counters
            d.qpos[:] = qpos[k]
            d.qvel[:] = qvel[k]
            if ctrl is not None:
                d.ctrl[:] = ctrl[k]
            mujoco.mj_forward(mm, d)
            mujoco.mj_getState(mm, d, self.state[i], _FULL)
            self.sensordata[i] = d.sensordata
            self.warmstart[i] = 0.0
            d.qacc_warmstart[:] = 0.0

    def add_velocity(self, idx: np.ndarray, dqvel: np.ndarray) -> None:
        """Adds ``dqvel [len(idx), nv]`` to the velocities of envs ``idx`` (an impulse such as a push).

        Time, positions and the solver warm start are kept; ``sensordata`` is refreshed by the next step.
        """
        idx = np.asarray(idx, dtype=np.int64).reshape(-1)
        if idx.size == 0:
            return
        self.qvel[idx] += np.asarray(dqvel, dtype=np.float64).reshape(idx.size, self.nv)
        if self.engine == "step":
            for i in idx:
                self.datas[i].qvel[:] = self.qvel[i]

    def reset_all_to(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        self.set_state(np.arange(self.num_envs), qpos, qvel)

    def step(self, ctrl: np.ndarray) -> np.ndarray:
        """Advances every env ``nsub`` substeps with ``ctrl [M, nu]`` held; returns ``unstable [M]`` bool.

        After the call ``qpos/qvel/sensordata`` hold the new state; ``sensordata`` is what MuJoCo
        computed during the last substep (as after ``mj_step``).
        """
        ctrl = np.asarray(ctrl, dtype=np.float64)
        if self.engine == "step":
            return self._step_loop(ctrl)
        return self._step_rollout(ctrl)

    def _sensors(self, on: bool) -> None:
        if not self._split:
            return
        for mm in self._unique_models:
            if on:
                mm.opt.disableflags &= ~_SENSOR_OFF
            else:
                mm.opt.disableflags |= _SENSOR_OFF

    def _step_loop(self, ctrl: np.ndarray) -> np.ndarray:
        unstable = np.zeros(self.num_envs, dtype=bool)
        for i, d in enumerate(self.datas):
            mm = self._data_models[i]
            before = sum(d.warning[w].number for w in _BAD_WARNINGS)
            d.ctrl[:] = ctrl[i]
            if self._split:
                flags = mm.opt.disableflags
                mm.opt.disableflags = flags | _SENSOR_OFF
                try:
                    mujoco.mj_step(mm, d, self.nsub - 1)
                finally:
                    mm.opt.disableflags = flags
                mujoco.mj_step(mm, d, 1)
            else:
                mujoco.mj_step(mm, d, self.nsub)
            if sum(d.warning[w].number for w in _BAD_WARNINGS) != before:
                unstable[i] = True
            mujoco.mj_getState(mm, d, self.state[i], _FULL)
            self.sensordata[i] = d.sensordata
        return unstable | ~np.isfinite(self.state).all(axis=1)

    def _step_rollout(self, ctrl: np.ndarray) -> np.ndarray:
        nq, nv = self.nq, self.nv
        dt = self._dt if self._dt is not None else self.model.opt.timestep
        t0 = self.time.copy()
        try:
            for on, n, ctrl_buf, out_state, out_sens in self._phases:
                self._sensors(on)
                ctrl_buf[:] = ctrl[:, None, :]
                self._rollout.rollout(
                    self._data_models,
                    [self._scratch],
                    self.state,
                    ctrl_buf,
                    control_spec=mujoco.mjtState.mjSTATE_CTRL.value,
                    skip_checks=True,
                    nstep=n,
                    initial_warmstart=self.warmstart,
                    state=out_state,
                    sensordata=out_sens,
                )
                # Next warm start: the acceleration the last substep applied.
                prev_qvel = out_state[:, -2, 1 + nq : 1 + nq + nv] if n > 1 else self.qvel.copy()
                self.state[:] = out_state[:, -1]
                np.subtract(self.qvel, prev_qvel, out=self.warmstart)
                self.warmstart /= dt
        finally:
            self._sensors(True)
        self.sensordata[:] = self._phases[-1][4][:, -1]
        expected = t0 + self.nsub * (dt[:, 0] if self._dt is not None else dt)
        unstable = np.abs(self.time - expected) > 1e-6 * np.maximum(1.0, np.abs(expected))
        unstable |= ~np.isfinite(self.state).all(axis=1)
        self.warmstart[unstable] = 0.0
        return unstable

    def scene(self, env: int) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """(model, data) of env ``env``: its model and a render-only MjData holding its current state with
        kinematics computed (``mj_forward``), for ``mujoco.Renderer``. The data is reused by the next call."""
        if not 0 <= env < self.num_envs:
            raise IndexError(f"env {env} out of range for {self.num_envs} envs")
        model = self._data_models[env]
        if self._view is None:
            self._view = mujoco.MjData(self.model)
        mujoco.mj_setState(model, self._view, self.state[env], _FULL)
        mujoco.mj_forward(model, self._view)
        return model, self._view

    def close(self) -> None:
        if self.engine == "rollout":
            self._rollout.close()


def _bench(engine: str, num_envs: int = 256, steps: int = 100) -> tuple[float, float]:  # pragma: no cover
    """(task, physics-only) env steps per CPU second of go1_joystick_flat with random actions."""
    import tasks

    task = tasks.make("go1_joystick_flat", num_envs, seed=0, overrides={"physics_engine": engine})
    task.reset()
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, size=(steps + 1, num_envs, task.spec.action_dim)).astype(np.float32)
    task.step(acts[0])
    # CPU time of this (single-threaded) process: the one-core rate even on a busy machine.
    t = time.process_time()
    for a in acts[1:]:
        task.step(a)
    full = steps * num_envs / (time.process_time() - t)
    ctrl = task.default_pose + 0.5 * acts[1:].astype(np.float64)
    t = time.process_time()
    for c in ctrl:
        task.sim.step(c)
    phys = steps * num_envs / (time.process_time() - t)
    task.close()
    return full, phys


if __name__ == "__main__":  # pragma: no cover
    # One process, one thread (pin it with `taskset -c N` for a one-core number); best of 3, interleaved.
    import sys

    n = int(sys.argv[1]) if len(sys.argv) > 1 else 256
    best = {e: (0.0, 0.0) for e in ENGINES}
    for _ in range(3):
        for eng in ENGINES:
            f, p = _bench(eng, n)
            best[eng] = (max(best[eng][0], f), max(best[eng][1], p))
    for eng, (f, p) in best.items():
        print(f"go1_joystick_flat num_envs={n} engine={eng}: task.step {f:.0f} env steps/s, "
              f"physics only {p:.0f} env steps/s")
