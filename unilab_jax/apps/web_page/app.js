// The page: loads task.json, the model (MuJoCo WebAssembly), the policy (onnxruntime-web) and the robot's task
// module, runs policy and physics in real time (or as fast as possible with ?speed=max, or only through
// window.unilab.advance with ?speed=0), maps the arrow keys to the velocity command and draws the model's
// geoms with three.js (not with ?view=0: a browser without a GPU spends its time drawing). window.unilab
// exposes the state to tests.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import loadMujoco from "./vendor/mujoco/mujoco.js";
import * as ort from "./vendor/ort/ort.wasm.min.mjs";

const params = new URLSearchParams(location.search);
const speedParam = params.get("speed") ?? "1";
const MAX = speedParam === "max";
const SPEED = MAX ? Infinity : Number(speedParam);
const VIEW = params.get("view") !== "0";
const status = document.getElementById("status");
const hud = document.getElementById("hud");

const unilab = { ready: false, error: null };
window.unilab = unilab;

function fail(e) {
  unilab.error = String(e && e.stack ? e.stack : e);
  status.textContent = "error: " + String(e);
  console.error(e);
}

async function main() {
  const spec = await (await fetch("task.json")).json();
  status.textContent = "loading MuJoCo ...";
  const mujoco = await loadMujoco();
  const xml = await (await fetch(spec.model)).text();
  const model = mujoco.MjModel.from_xml_string(xml);
  const data = new mujoco.MjData(model);
  status.textContent = "loading the policy ...";
  ort.env.wasm.wasmPaths = new URL("vendor/ort/", location.href).href;
  ort.env.wasm.numThreads = 1;
  const session = await ort.InferenceSession.create(spec.policy, { executionProviders: ["wasm"] });
  const { Task } = await import("./" + spec.module);
  const task = new Task(mujoco, model, data, spec);
  task.reset();

  // ---- simulation -------------------------------------------------------------------------------------
  let steps = 0, falls = 0, lastAction = new Float32Array(spec.action_dim);
  let rawYaw = baseYaw(data), yaw = rawYaw; // yaw: unwrapped (counts whole turns)
  let trace = null; // [{obs, action}] while advance(n, true) runs

  function baseYaw(d) {
    const [w, x, y, z] = d.qpos.subarray(3, 7);
    return Math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z));
  }

  async function stepOnce() {
    const obs = Float32Array.from(task.obs);
    const out = await session.run({ obs: new ort.Tensor("float32", obs, [1, spec.obs_dim]) });
    lastAction = Float32Array.from(out.action.data);
    if (trace) trace.push({ obs: Array.from(obs), action: Array.from(lastAction) });
    task.step(lastAction);
    steps += 1;
    const y = baseYaw(data);
    yaw += Math.atan2(Math.sin(y - rawYaw), Math.cos(y - rawYaw));
    rawYaw = y;
    if (task.fallen) {
      falls += 1;
      reset();
    }
  }

  function reset() {
    task.reset();
    rawYaw = yaw = baseYaw(data);
  }

  // One runner at a time: real-time loop, fast loop and advance() queue on this chain.
  let chain = Promise.resolve();
  const queue = (fn) => (chain = chain.then(fn, fn));

  function state() {
    const q = data.qpos;
    return {
      time: steps * spec.ctrl_dt, steps, falls, yaw,
      pos: [q[0], q[1], q[2]], command: Array.from(task.command),
    };
  }

  // ---- keys -------------------------------------------------------------------------------------------
  const held = new Set();
  const KEYS = ["ArrowUp", "ArrowDown", "ArrowLeft", "ArrowRight"];
  function commandFromKeys() {
    const f = spec.keys.forward, r = spec.keys.yaw_rate;
    task.command[0] = (held.has("ArrowUp") ? f : 0) - (held.has("ArrowDown") ? f : 0);
    task.command[1] = 0;
    task.command[2] = (held.has("ArrowLeft") ? r : 0) - (held.has("ArrowRight") ? r : 0);
  }
  window.addEventListener("keydown", (e) => {
    if (KEYS.includes(e.key)) {
      held.add(e.key);
      commandFromKeys();
      e.preventDefault();
    } else if (e.key === "r" || e.key === "R") {
      queue(reset);
    }
  });
  window.addEventListener("keyup", (e) => {
    if (KEYS.includes(e.key)) {
      held.delete(e.key);
      commandFromKeys();
    }
  });
  window.addEventListener("blur", () => {
    held.clear();
    commandFromKeys();
  });

  // ---- the test API -----------------------------------------------------------------------------------
  Object.assign(unilab, {
    spec,
    state,
    observation: () => Array.from(task.obs),
    action: () => Array.from(lastAction),
    qpos: () => Array.from(data.qpos),
    setCommand: (c) => task.command.set(c),
    reset: () => queue(() => { reset(); steps = 0; falls = 0; return state(); }),
    // n control steps now; with record, the (obs, action) of each step and the observation after the last.
    advance: (n, record = false) => queue(async () => {
      trace = record ? [] : null;
      for (let i = 0; i < n; i++) await stepOnce();
      const out = { state: state(), trace, obs: Array.from(task.obs) };
      trace = null;
      return out;
    }),
  });

  // ---- view -------------------------------------------------------------------------------------------
  const view = VIEW ? makeView(mujoco, model, data) : { draw: () => {} };

  // ---- run --------------------------------------------------------------------------------------------
  if (MAX) {
    const pump = () => queue(async () => {
      const t0 = performance.now();
      while (performance.now() - t0 < 20) await stepOnce();
    }).then(() => setTimeout(pump, 0), fail);
    pump();
  } else if (SPEED > 0) {
    let wall = performance.now(), owed = 0;
    const tick = () => queue(async () => {
      const now = performance.now();
      owed = Math.min(owed + ((now - wall) / 1000) * SPEED, 0.5); // at most 0.5 s to catch up
      wall = now;
      while (owed >= spec.ctrl_dt) {
        await stepOnce();
        owed -= spec.ctrl_dt;
      }
    }).then(() => requestAnimationFrame(tick), fail);
    requestAnimationFrame(tick);
  }
  const draw = () => {
    view.draw();
    const s = state();
    hud.textContent =
      `t ${s.time.toFixed(1)} s   command vx ${s.command[0].toFixed(2)} m/s  yaw ${s.command[2].toFixed(2)} rad/s` +
      `   x ${s.pos[0].toFixed(2)} y ${s.pos[1].toFixed(2)}   falls ${s.falls}`;
    requestAnimationFrame(draw);
  };
  requestAnimationFrame(draw);
  status.textContent = "";
  unilab.ready = true;
}

// three.js meshes for the model's geoms (plane, sphere, capsule, ellipsoid, cylinder, box), posed from
// data.geom_xpos / geom_xmat; z is up, the camera follows the base.
function makeView(mujoco, model, data) {
  const canvas = document.getElementById("view");
  let renderer;
  try {
    renderer = new THREE.WebGLRenderer({ canvas, antialias: true });
  } catch (e) {
    status.textContent = "no WebGL in this browser: the simulation runs, the view stays empty";
    return { draw: () => {} };
  }
  renderer.setPixelRatio(window.devicePixelRatio);
  renderer.shadowMap.enabled = true;
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xdfe8f0);
  scene.fog = new THREE.Fog(0xdfe8f0, 8, 30);
  const camera = new THREE.PerspectiveCamera(45, 1, 0.05, 100);
  camera.up.set(0, 0, 1);
  camera.position.set(-1.2, -1.6, 0.9);
  const controls = new OrbitControls(camera, canvas);
  controls.target.set(0, 0, 0.25);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x667788, 1.6));
  const sun = new THREE.DirectionalLight(0xffffff, 2.0);
  sun.position.set(2, -3, 5);
  sun.castShadow = true;
  sun.shadow.mapSize.set(1024, 1024);
  Object.assign(sun.shadow.camera, { left: -2, right: 2, top: 2, bottom: -2, near: 0.1, far: 20 });
  scene.add(sun, sun.target);

  const size = model.geom_size, types = model.geom_type, bodies = model.geom_bodyid;
  const meshes = [];
  for (let i = 0; i < model.ngeom; i++) {
    const [a, b, c] = size.subarray(3 * i, 3 * i + 3);
    let geometry, material;
    const t = types[i];
    if (t === 0) { // plane: a checkered floor
      geometry = new THREE.PlaneGeometry(60, 60);
      material = new THREE.MeshStandardMaterial({ map: checker(), roughness: 0.9 });
    } else {
      if (t === 2) geometry = new THREE.SphereGeometry(a, 20, 12);
      else if (t === 3) geometry = new THREE.CapsuleGeometry(a, 2 * b, 6, 12).rotateX(Math.PI / 2);
      else if (t === 4) geometry = new THREE.SphereGeometry(1, 20, 12).scale(a, b, c);
      else if (t === 5) geometry = new THREE.CylinderGeometry(a, a, 2 * b, 16).rotateX(Math.PI / 2);
      else if (t === 6) geometry = new THREE.BoxGeometry(2 * a, 2 * b, 2 * c);
      else continue;
      const trunk = bodies[i] === 1, foot = t === 2;
      material = new THREE.MeshStandardMaterial({
        color: foot ? 0x222222 : trunk ? 0x3b4a5a : 0xd9822b, roughness: 0.5, metalness: 0.1,
      });
    }
    const mesh = new THREE.Mesh(geometry, material);
    mesh.castShadow = t !== 0;
    mesh.receiveShadow = t === 0;
    mesh.matrixAutoUpdate = false;
    scene.add(mesh);
    meshes.push([i, mesh]);
  }
  const m4 = new THREE.Matrix4();
  let last = null;

  function resize() {
    const w = canvas.clientWidth, h = canvas.clientHeight;
    if (canvas.width !== Math.floor(w * renderer.getPixelRatio()) || canvas.height !== Math.floor(h * renderer.getPixelRatio())) {
      renderer.setSize(w, h, false);
      camera.aspect = w / h;
      camera.updateProjectionMatrix();
    }
  }

  return {
    draw() {
      resize();
      const xpos = data.geom_xpos, xmat = data.geom_xmat;
      for (const [i, mesh] of meshes) {
        const p = xpos.subarray(3 * i, 3 * i + 3), r = xmat.subarray(9 * i, 9 * i + 9);
        m4.set(r[0], r[1], r[2], p[0], r[3], r[4], r[5], p[1], r[6], r[7], r[8], p[2], 0, 0, 0, 1);
        mesh.matrix.copy(m4);
      }
      const base = new THREE.Vector3(data.qpos[0], data.qpos[1], data.qpos[2]);
      if (last) {
        const d = base.clone().sub(last);
        d.z = 0;
        camera.position.add(d);
        controls.target.add(d);
      }
      last = base;
      sun.position.set(base.x + 2, base.y - 3, 5);
      sun.target.position.copy(base);
      controls.update();
      renderer.render(scene, camera);
    },
  };
}

function checker() {
  const c = document.createElement("canvas");
  c.width = c.height = 64;
  const g = c.getContext("2d");
  for (let i = 0; i < 2; i++) {
    for (let j = 0; j < 2; j++) {
      g.fillStyle = (i + j) % 2 ? "#b8c4cc" : "#e8eef2";
      g.fillRect(32 * i, 32 * j, 32, 32);
    }
  }
  const tex = new THREE.CanvasTexture(c);
  tex.wrapS = tex.wrapT = THREE.RepeatWrapping;
  tex.repeat.set(60, 60); // 1 m squares
  tex.colorSpace = THREE.SRGBColorSpace;
  return tex;
}

main().catch(fail);
