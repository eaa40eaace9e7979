"""Success rate of the scripted experts, per task and variant, over N seeds.

    python benchmarks/bench_experts.py                      # every registered expert, 100 seeds
    python benchmarks/bench_experts.py --tasks Lift,Square --seeds 50 --start-seed 1000

Seed ``s`` resets the env with ``s`` and draws the expert's random choices from
``default_rng(s)`` (as ``actionflow-collect`` does). Prints one JSON object: per task the
successes, seeds, success rate, mean episode length of the successes (steps at 20 Hz), the
failed seeds and the wall time; plus the date, device and command. ``--actions-out FILE.npz``
also saves every episode's actions (key ``<task>/<seed>``, ``(T, 10)``), so that two versions of
the experts can be compared action by action.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import sys
import time

import gymnasium as gym
import numpy as np

import lerobot_actionflow.envs  # noqa: F401  (gym ids)
from lerobot_actionflow.envs.tasks import get_task
from lerobot_actionflow.experts import EXPERTS, make_expert
from lerobot_actionflow.experts.rollout import run_episode


def bench_task(task: str, seeds: range, actions: dict[str, np.ndarray] | None = None) -> dict:
    spec = get_task(task)
    env = gym.make(spec.gym_id, render_mode=None)
    expert = make_expert(spec.name, env)
    ok, lengths, failed = 0, [], []
    t0 = time.perf_counter()
    try:
        for s in seeds:
            ep = run_episode(env, expert, s, record=actions is not None)
            if actions is not None:
                actions[f"{spec.name}/{s}"] = np.asarray(ep.actions)
            if ep.success:
                ok += 1
                lengths.append(ep.steps)
            else:
                failed.append(s)
    finally:
        env.close()
    n = len(seeds)
    return {
        "task": spec.name,
        "variant": spec.variant,
        "expert_version": type(expert).version,
        "successes": ok,
        "seeds": n,
        "success_rate": ok / n if n else None,
        "mean_steps": round(float(np.mean(lengths)), 1) if lengths else None,
        "failed_seeds": failed,
        "seconds": round(time.perf_counter() - t0, 1),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default=",".join(EXPERTS), help="comma-separated tasks (default: all experts)")
    p.add_argument("--seeds", type=int, default=100, help="seeds per task")
    p.add_argument("--start-seed", type=int, default=0)
    p.add_argument("--actions-out", default=None, help="save every episode's actions to this .npz")
    args = p.parse_args(argv)
    results = []
    actions: dict[str, np.ndarray] | None = {} if args.actions_out else None
    for task in [t.strip() for t in args.tasks.split(",") if t.strip()]:
        r = bench_task(task, range(args.start_seed, args.start_seed + args.seeds), actions)
        print(f"{r['task']}: {r['successes']}/{r['seeds']} ({r['seconds']} s)", file=sys.stderr, flush=True)
        results.append(r)
    out = {
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "device": f"{platform.machine()} CPU, {os.cpu_count()} cores, {platform.platform()}",
        "command": " ".join(["python", *sys.argv]),
        "numpy": np.__version__,
        "results": results,
    }
    print(json.dumps(out, indent=2))
    if actions is not None:
        np.savez_compressed(args.actions_out, **actions)
    return 0


if __name__ == "__main__":
    sys.exit(main())
