"""The main job, end to end through LeRobot's own CLIs: collect -> train ActionFlow -> evaluate.

    actionflow-demo                      # Lift, a few minutes on a CPU
    actionflow-demo --task StackThree_D0 --episodes 100 --steps 20000 --device cuda

1. ``actionflow-collect`` records expert demonstrations into a LeRobotDataset (resumable);
2. ``actionflow-train --policy.type=actionflow`` trains on it (``lerobot-train``'s arguments and
   training loop, the dataset served from RAM: :mod:`lerobot_actionflow.train`), a checkpoint at
   the end;
3. ``lerobot-eval --env.type=actionflow`` rolls the policy out, records videos;
4. the success rate and where the videos are are printed.

Each stage streams its own progress and its wall time is printed at the end. A stage whose
output already exists is reused, so an interrupted demo continues where it stopped (``--fresh``
starts over).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

#: Small ActionFlow that trains in minutes on two CPU cores.
CPU_POLICY = [
    "--policy.dim=64",
    "--policy.num_layers=2",
    "--policy.num_heads=4",
    "--policy.head_dim=16",
    "--policy.n_obs_steps=1",
    "--policy.horizon=8",
    "--policy.n_action_steps=4",
    "--policy.scheduler_warmup_steps=100",
    "--policy.optimizer_lr=1e-3",
]


def _bin(name: str) -> str:
    """A console script of this environment (next to the running interpreter)."""
    path = Path(sys.executable).with_name(name)
    return str(path) if path.exists() else name


def train_command() -> list[str]:
    """``actionflow-train``, or ``python -m lerobot_actionflow.train`` where the console script is
    not installed next to the interpreter (an editable checkout not reinstalled since it was added)."""
    path = Path(sys.executable).with_name("actionflow-train")
    return [str(path)] if path.exists() else [sys.executable, "-m", "lerobot_actionflow.train"]


def _run(cmd: list[str], env: dict[str, str]) -> float:
    """Run ``cmd``; its wall time in seconds (exit on failure)."""
    print("\n$ " + " ".join(cmd), flush=True)
    start = time.perf_counter()
    code = subprocess.call(cmd, env=env)
    if code != 0:
        raise SystemExit(f"actionflow-demo: '{Path(cmd[0]).name}' failed with exit code {code}")
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="Lift")
    ap.add_argument("--episodes", type=int, default=30, help="demonstrations to collect")
    ap.add_argument("--steps", type=int, default=600, help="training steps")
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--eval-episodes", type=int, default=10)
    ap.add_argument("--eval-batch-size", type=int, default=2)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--output", type=Path, default=Path("outputs/demo"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--full-size", action="store_true", help="the default ActionFlow size instead of the CPU one"
    )
    ap.add_argument("--fresh", action="store_true", help="delete earlier outputs of this demo first")
    args = ap.parse_args(argv)

    out = args.output.resolve()
    if args.fresh and out.exists():
        shutil.rmtree(out)
    data, run, evaluation = out / "data", out / "train", out / "eval"
    repo_id = f"local/{args.task.lower()}_demo"
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    env.setdefault("MUJOCO_GL", "egl")
    # Small models on a few cores: one intra-op thread per process, so that the policy and the
    # env workers never spin-wait against each other.
    env.setdefault("OMP_NUM_THREADS", "1")
    seconds: dict[str, float] = {}

    print(f"[1/3] collecting {args.episodes} expert demonstrations of {args.task} into {data}", flush=True)
    seconds["collect"] = _run(
        [_bin("actionflow-collect"), "--task", args.task, "--episodes", str(args.episodes),
         "--root", str(data), "--repo-id", repo_id, "--seed", str(args.seed)],
        env,
    )  # fmt: skip

    checkpoint = run / "checkpoints" / "last" / "pretrained_model"
    if checkpoint.exists():
        print(f"[2/3] reusing the trained policy in {checkpoint}", flush=True)
    else:
        print(f"[2/3] training ActionFlow for {args.steps} steps on {args.device}", flush=True)
        if run.exists():  # a run interrupted before its first checkpoint
            shutil.rmtree(run)
        # The dataset is served from RAM in the training process: no loader workers.
        seconds["train"] = _run(
            [*train_command(), "--policy.type=actionflow", f"--policy.device={args.device}",
             "--policy.push_to_hub=false", f"--dataset.repo_id={repo_id}", f"--dataset.root={data}",
             f"--output_dir={run}", f"--steps={args.steps}", f"--save_freq={args.steps}",
             f"--batch_size={args.batch_size}", "--num_workers=0", "--log_freq=100", "--wandb.enable=false",
             f"--seed={args.seed}", *([] if args.full_size else CPU_POLICY)],
            env,
        )  # fmt: skip

    print(f"[3/3] evaluating on {args.eval_episodes} episodes with lerobot-eval", flush=True)
    if evaluation.exists():
        shutil.rmtree(evaluation)
    seconds["evaluate"] = _run(
        [_bin("lerobot-eval"), f"--policy.path={checkpoint}", f"--policy.device={args.device}",
         "--env.type=actionflow", f"--env.task={args.task}", f"--eval.n_episodes={args.eval_episodes}",
         f"--eval.batch_size={args.eval_batch_size}", f"--output_dir={evaluation}",
         f"--seed={args.seed + 1000}"],
        env,
    )  # fmt: skip

    info = json.loads((evaluation / "eval_info.json").read_text())
    success = info.get("overall", info.get("aggregated", {})).get("pc_success")
    videos = sorted(evaluation.rglob("*.mp4"))
    print("\n=== actionflow-demo ===")
    print(f"task: {args.task}; demonstrations: {args.episodes}; training steps: {args.steps}")
    print(f"success rate over {args.eval_episodes} episodes: {success}%")
    print(f"checkpoint: {checkpoint}")
    print(f"videos: {videos[0].parent if videos else 'none written'} ({len(videos)} files)")
    print(f"eval details: {evaluation / 'eval_info.json'}")
    print("wall time: " + ", ".join(f"{stage} {s:.0f} s" for stage, s in seconds.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
