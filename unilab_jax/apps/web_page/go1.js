// go1_joystick_flat in the page: what tasks/go1_joystick.py's step and tasks/go1_math.py's actor_obs compute
// at evaluation, without observation noise or domain randomisation. tests/test_web.py replays this page's
// actions in the Python task and compares the observations step by step.
//
// Observation (48, float32): local linear velocity 3, gyro 3, gravity in the IMU frame 3, joint angles -
// default pose 12, joint velocities 12, last action 12, command 3. As in the task, the observation after a
// step is built before the step's bookkeeping: its "last action" is the previous step's action, and its
// command the one in force during the step.

export class Task {
  // mujoco: the loaded WebAssembly module; spec: the page's task.json.
  constructor(mujoco, model, data, spec) {
    this.mj = mujoco;
    this.model = model;
    this.data = data;
    this.spec = spec;
    this.nu = spec.action_dim;
    this.command = new Float64Array(3);
    this.lastAct = new Float64Array(this.nu);
    this.obs = new Float32Array(spec.obs_dim);
    this.fallen = false;
  }

  sensor(name) {
    const [adr, dim] = this.spec.sensors[name];
    return this.data.sensordata.subarray(adr, adr + dim);
  }

  // The task's reset at its home pose (base at the origin, yaw 0, at rest); sensors from mj_forward.
  reset() {
    const { mj, model, data, spec } = this;
    mj.mj_resetData(model, data);
    data.qpos.set(spec.home_qpos);
    data.ctrl.set(spec.default_pose);
    mj.mj_forward(model, data);
    this.lastAct.fill(0);
    this.fallen = false;
    this.observe();
  }

  // go1_math.actor_obs with zero noise, into this.obs.
  observe() {
    const o = this.obs, qpos = this.data.qpos, qvel = this.data.qvel, nu = this.nu;
    const v = this.sensor("local_linvel"), g = this.sensor("gyro"), q = this.sensor("orientation");
    const [w, x, y, z] = q;
    const gravity = [-2 * (x * z - w * y), -2 * (y * z + w * x), -(1 - 2 * (x * x + y * y))];
    let k = 0;
    for (let i = 0; i < 3; i++) o[k++] = v[i];
    for (let i = 0; i < 3; i++) o[k++] = g[i];
    for (let i = 0; i < 3; i++) o[k++] = gravity[i];
    for (let i = 0; i < nu; i++) o[k++] = qpos[7 + i] - this.spec.default_pose[i];
    for (let i = 0; i < nu; i++) o[k++] = qvel[6 + i];
    for (let i = 0; i < nu; i++) o[k++] = this.lastAct[i];
    for (let i = 0; i < 3; i++) o[k++] = this.command[i];
    return o;
  }

  // One control step: the action clipped to [-1, 1] (NaN -> 0), position targets default pose + scale *
  // action held for nsub physics steps, then the next observation; fallen when the torso's up-vector
  // points down (the task's termination).
  step(action) {
    const { mj, model, data, spec } = this;
    const a = new Float64Array(this.nu);
    for (let i = 0; i < this.nu; i++) {
      const ai = Number.isNaN(action[i]) ? 0 : action[i];
      a[i] = Math.min(1, Math.max(-1, ai));
    }
    const ctrl = data.ctrl;
    for (let i = 0; i < this.nu; i++) ctrl[i] = spec.default_pose[i] + a[i] * spec.action_scale;
    for (let s = 0; s < spec.nsub; s++) mj.mj_step(model, data);
    this.observe();
    this.lastAct = a;
    this.fallen = this.sensor("upvector")[2] < 0;
    return this.obs;
  }
}
