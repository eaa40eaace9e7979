"""Env speed: steps/s of each pose-token task against its raw robosuite env.

Both envs are built with the same robosuite settings (``make_robosuite_env``) and driven by
the same slowly moving absolute EEF target; the raw env receives robosuite's 7-D action
precomputed, the wrapper the 10-D action (so validation, 6D -> axis-angle conversion,
observation building and the success check count as overhead). Timings are best-of
``--repeats`` blocks of ``--steps`` steps, raw and wrapped blocks interleaved, after a warm-up.
Prints one JSON object; ``overhead`` = 1 - wrapped/raw steps per second (noisy on a shared
machine), ``wrapper_share_of_raw_step`` = the wrapper's own work per step, timed alone,
divided by the raw step time (the robust figure).

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_env_speed.py [--tasks Lift Square] [--steps 200]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np


def _targets(env, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """10-D wrapper actions and the matching robosuite actions: a small circle around the start."""
    pos, mat = env.unwrapped.eef_pose()
    t = np.arange(steps) / 20.0
    acts = np.zeros((steps, 10), np.float32)
    acts[:, 0] = pos[0] + 0.05 * np.sin(2 * np.pi * 0.25 * t)
    acts[:, 1] = pos[1] + 0.05 * np.cos(2 * np.pi * 0.25 * t) - 0.05
    acts[:, 2] = pos[2] - 0.05
    acts[:, 3:6], acts[:, 6:9] = mat[:, 0], mat[:, 1]
    acts[:, 9] = np.where(t % 2 < 1, -1.0, 1.0)
    raw = np.stack([env.unwrapped.to_robosuite_action(a) for a in acts])
    return acts, raw


def bench_task(task: str, steps: int, repeats: int) -> dict:
    import gymnasium as gym

    import lerobot_actionflow.envs  # noqa: F401
    from lerobot_actionflow.envs import get_task
    from lerobot_actionflow.envs.pose_env import make_robosuite_env

    spec = get_task(task)
    wrapped = gym.make(spec.gym_id, render_mode=None, terminate_on_success=False)
    raw = make_robosuite_env(spec)
    wrapped.reset(seed=0)
    acts, raw_acts = _targets(wrapped, steps)
    best = {"raw": float("inf"), "wrapped": float("inf")}
    for rep in range(repeats + 1):  # the first block of each is a warm-up
        raw.reset()
        t0 = time.perf_counter()
        for a in raw_acts:
            raw.step(a)
        t_raw = time.perf_counter() - t0
        wrapped.reset(seed=0)
        t0 = time.perf_counter()
        for a in acts:
            wrapped.step(a)
        t_wrapped = time.perf_counter() - t0
        if rep:
            best["raw"] = min(best["raw"], t_raw)
            best["wrapped"] = min(best["wrapped"], t_wrapped)
    # The wrapper's own work per step, timed alone (robust to a busy machine): action check and
    # conversion, observation (success is read off robosuite's sparse reward, no extra check).
    env = wrapped.unwrapped
    t0 = time.perf_counter()
    for a in acts:
        env.to_robosuite_action(a)
        env.get_observation()
    own_us = (time.perf_counter() - t0) / steps * 1e6
    wrapped.close()
    raw.close()
    raw_sps, wrapped_sps = steps / best["raw"], steps / best["wrapped"]
    return {
        "raw_steps_per_s": round(raw_sps, 1),
        "wrapped_steps_per_s": round(wrapped_sps, 1),
        "overhead": round(1 - wrapped_sps / raw_sps, 4),
        "wrapper_us_per_step": round(own_us, 1),
        "wrapper_share_of_raw_step": round(own_us * 1e-6 * raw_sps, 4),
    }


def main() -> None:
    from lerobot_actionflow.envs import TASKS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="*", default=sorted(TASKS))
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    results = {t: bench_task(t, args.steps, args.repeats) for t in args.tasks}
    print(
        json.dumps(
            {
                "benchmark": "env_speed",
                "date": time.strftime("%Y-%m-%d", time.gmtime()),
                "device": f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, "
                "no rendering",
                "steps": args.steps,
                "repeats": args.repeats,
                "tasks": results,
                "max_overhead": max(r["overhead"] for r in results.values()),
                "max_wrapper_share": max(r["wrapper_share_of_raw_step"] for r in results.values()),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
