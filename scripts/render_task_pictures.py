"""The README's task pictures: ``docs/tasks/<Task>.png``, each task's first frame.

    python scripts/render_task_pictures.py                          # every task
    python scripts/render_task_pictures.py MugHang_D0 MugHang_Moved

A picture is ``env.render()`` (the ``agentview`` camera, 256 x 256) right after
``env.reset(seed=0)``: the initial layout of seed 0.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import gymnasium as gym
from PIL import Image

import lerobot_actionflow.envs as envs

OUT = Path(__file__).resolve().parents[1] / "docs" / "tasks"


def render(task: str, out: Path = OUT, seed: int = 0) -> Path:
    """Write ``out/<task>.png``; returns its path."""
    spec = envs.get_task(task)
    env = gym.make(spec.gym_id)
    try:
        env.reset(seed=seed)
        path = out / f"{spec.name}.png"
        Image.fromarray(env.render()).save(path)
    finally:
        env.close()
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("tasks", nargs="*", help="task names (default: every registered task)")
    p.add_argument("--out", type=Path, default=OUT)
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for task in args.tasks or list(envs.TASKS):
        print(render(task, args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
