"""SAC on ``robot_reach`` from the wrist camera, in one process: the pixel-only learning test's run and measurement.

    MUJOCO_GL=egl python tests/robots/pixel_reach.py --observation=images --seed=0 [--steps=2400]

The target (a green disc placed at random on the table) is in no observation but the image: the policy reads
proprioception (tcp, gripper, velocity) and the robot's kind, and with ``--observation=images`` the wrist camera's
16 x 16 frame; the critic reads the same (``critic_state`` off), or with ``--asymmetric`` the privileged state too
(the target's position) and the actor its own encoder (``actor_encoder``). ``--observation=blind``: proprioception
only, the same learner without images. In-process simulated Frankas (unpaced, the arm drawn with its collision
shapes: ~4 ms a frame in software GL), episodes of 12 steps, rotation locked, dense reward (potential shaping, 10 on
success); a replay of every transition; after 400 random steps, 2 learner calls of 2 SAC gradient steps per step of
the 4 robots (utd 1). No DrQ shift by default (``--pad``): at 16 px a pixel of the wrist frame spans ~3 cm of table,
more than the 2 cm success radius, and nothing in the frame marks the tcp (a shift moves the target against the
frame itself); seed 2 measured 0.34 with a 1-pixel shift, 1.0 without. Prints one JSON line: the deterministic
policy's success rate over 32 fresh episodes, wall and CPU seconds.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

ENVS, UPDATES, CALLS, BATCH, RANDOM_STEPS = 4, 2, 2, 128, 400
FIELDS = ("obs", "critic_obs", "action", "reward", "next_obs", "next_critic_obs", "terminated", "truncated")
IMAGE_FIELDS = ("image", "next_image")


def task_overrides(images: bool, asymmetric: bool, size: int = 16) -> dict:
    return {"episode_length": 12, "lock_rotation": True, "critic_state": asymmetric, "camera_geometry": "collision",
            "dense_reward": True, "cameras": ("wrist",) if images else (), "image_size": size}


def run(observation: str, seed: int, steps: int, asymmetric: bool = False, calls: int = CALLS, pad: int = 0,
        size: int = 16) -> dict:
    import jax

    import tasks
    from unilab_jax import nets
    from unilab_jax.algos.offpolicy import sac
    from unilab_jax.algos.offpolicy.learner_jax import SACFamilyLearner
    from unilab_jax.training.evaluation import deterministic_policy, run_episodes

    start, cpu = time.perf_counter(), time.process_time()
    images = observation == "images"
    task = tasks.make("robot_reach", ENVS, seed, task_overrides(images, asymmetric, size))
    config = sac.Config(actor_hidden=(64, 64), critic_hidden=(64, 64), batch_size=BATCH, updates_per_call=UPDATES,
                        gamma=0.9, actor_learning_rate=1e-3, critic_learning_rate=1e-3, alpha_learning_rate=1e-3,
                        init_alpha=0.05, encoder_channels=(8, 8), encoder_strides=(2, 1), feature_dim=16,
                        image_pad=pad, actor_encoder=asymmetric)
    learner = SACFamilyLearner(sac, config, task.spec)
    state = learner.init(jax.random.PRNGKey(seed))
    rng = np.random.default_rng(seed)
    fields = FIELDS + (IMAGE_FIELDS if images else ())
    replay: dict[str, np.ndarray] = {}
    rows = 0
    obs, critic = task.reset()
    weights = nets.to_numpy(learner.weights(state))
    try:
        for _ in range(steps // ENVS):
            if rows < RANDOM_STEPS:
                action = rng.uniform(-1.0, 1.0, (ENVS, task.spec.action_dim)).astype(np.float32)
            else:
                noise = rng.normal(size=(ENVS, task.spec.action_dim)).astype(np.float32)
                action = sac.act(weights, obs, noise, False, **({"image": task.images()} if images else {}))[0]
            out = task.step(action)
            row = {"obs": obs, "critic_obs": critic, "action": action, "reward": out.reward, "next_obs": out.next_obs,
                   "next_critic_obs": out.next_critic_obs, "terminated": out.terminated, "truncated": out.truncated,
                   **{k: out.extras[k] for k in IMAGE_FIELDS if images}}
            for k in fields:
                if k not in replay:
                    replay[k] = np.zeros((steps, *np.shape(row[k])[1:]), np.asarray(row[k]).dtype)
                replay[k][rows:rows + ENVS] = row[k]
            rows += ENVS
            obs, critic = out.obs, out.critic_obs
            if rows >= RANDOM_STEPS:
                for _ in range(calls):
                    idx = rng.integers(0, rows, (UPDATES, BATCH))
                    state, _ = learner.update(state, {k: replay[k][idx] for k in fields})
                weights = nets.to_numpy(learner.weights(state))
        train_s = time.perf_counter() - start
        successes = [run_episodes(task, deterministic_policy(sac, weights, task))[1]["success_rate"] for _ in range(8)]
    finally:
        task.close()
    return {"observation": observation, "asymmetric": asymmetric, "seed": seed, "steps": rows, "calls": calls,
            "pad": pad, "size": size,
            "success_rate": float(np.mean(successes)), "train_s": round(train_s, 1),
            "total_s": round(time.perf_counter() - start, 1), "cpu_s": round(time.process_time() - cpu, 1)}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--observation", choices=("images", "blind"), default="images")
    p.add_argument("--asymmetric", action="store_true")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=2400)
    p.add_argument("--calls", type=int, default=CALLS, help="learner calls per step of the robots")
    p.add_argument("--pad", type=int, default=0, help="DrQ shift (pixels)")
    p.add_argument("--size", type=int, default=16, help="camera pixels per side")
    args = p.parse_args()
    print(json.dumps(run(args.observation, args.seed, args.steps, args.asymmetric, args.calls, args.pad, args.size)),
          flush=True)


if __name__ == "__main__":
    main()
