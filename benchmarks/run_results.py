"""The results table of issue #7 for one task: three policies, one dataset, IS sweep, generalisation.

Stages (each skipped when its output exists, so an interrupted run continues):

1. ``actionflow-collect``: ``--episodes`` expert demonstrations of ``--task`` (seed ``--seed``);
2. ``actionflow-train`` (``lerobot-train``'s loop, the dataset served from RAM, no loader
   workers) of ``actionflow``, ``euclidean_flow`` (the diffusion UNet backbone, so that it
   differs from Diffusion Policy only by the flow) and LeRobot's ``diffusion`` on that dataset,
   the same steps, batch, history, horizon and executed actions for all three;
3. ``lerobot_actionflow.evaluation.sweep``: success against inference steps IS on the training
   distribution, the same evaluation seeds for every cell;
4. the same sweep at one IS (``--generalisation-is``) on other evaluation envs: the task's D1/D2
   variants (mimicgen tasks) and scene-transformed layouts (``--env.scene_*``), with and without
   the robot moved along.

Writes ``<output>/results.json`` and prints markdown tables. ``--preset cpu`` is the small
configuration measured on a 2-core CPU (see benchmarks/RESULTS.md); ``--preset paper`` keeps
each policy's default size for a GPU.

    python benchmarks/run_results.py --task Lift --output outputs/results/Lift
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from lerobot_actionflow.demo import train_command

POLICIES = ("actionflow", "euclidean_flow", "diffusion")
COMMON = ["--policy.n_obs_steps=2", "--policy.horizon=16", "--policy.n_action_steps=8"]
# Small models that train in minutes on a CPU; the widths are the policies' own knobs.
CPU_SIZE = {
    "actionflow": [
        "--policy.dim=64",
        "--policy.num_layers=2",
        "--policy.num_heads=4",
        "--policy.head_dim=16",
    ],
    "euclidean_flow": ["--policy.backbone=unet", "--policy.down_dims=[64,128,256]"],
    "diffusion": ["--policy.down_dims=[64,128,256]"],
}
PAPER_SIZE = {"actionflow": [], "euclidean_flow": ["--policy.backbone=unet"], "diffusion": []}
# Scene transforms of the generalisation table: name -> env overrides.
SCENES = {
    "shift+yaw, objects only": [
        "--env.scene_yaw=[-0.785,0.785]",
        "--env.scene_x=[-0.1,0.1]",
        "--env.scene_y=[-0.1,0.1]",
    ],
    "shift+yaw, robot moved too": [
        "--env.scene_yaw=[-0.785,0.785]",
        "--env.scene_x=[-0.1,0.1]",
        "--env.scene_y=[-0.1,0.1]",
        "--env.scene_move_robot=true",
    ],
}


def _bin(name: str) -> str:
    return str(Path(sys.executable).with_name(name))


def _run(cmd: list[str], env: dict, log: Path) -> None:
    print("$", " ".join(cmd), f"> {log}", flush=True)
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w") as f:
        subprocess.run(cmd, env=env, check=True, stdout=f, stderr=subprocess.STDOUT)


def _sweep(
    checkpoints: list[Path], task: str, steps: list[int], extra: list[str], out: Path, args, env
) -> list:
    result = out / "sweep_results.json"
    if not result.exists():
        _run(
            [sys.executable, "-m", "lerobot_actionflow.evaluation.sweep",
             f"--checkpoints=[{','.join(str(c) for c in checkpoints)}]",
             "--env.type=actionflow", f"--env.task={task}", *extra,
             *([f"--env.episode_length={args.episode_length}"] if args.episode_length else []),
             f"--inference_steps=[{','.join(map(str, steps))}]",
             f"--eval.n_episodes={args.eval_episodes}", f"--eval.batch_size={args.eval_batch_size}",
             f"--seed={args.eval_seed}", "--device=cpu", f"--output_dir={out}"],
            env, out / "sweep.log",
        )  # fmt: skip
    return json.loads(result.read_text())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="Lift")
    ap.add_argument("--output", type=Path, required=True)
    ap.add_argument("--episodes", type=int, default=50, help="expert demonstrations")
    ap.add_argument("--seed", type=int, default=0, help="collection and training seed")
    ap.add_argument("--steps", type=int, default=2000, help="training steps, every policy")
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--device", default="cpu", help="training device")
    ap.add_argument("--preset", choices=("cpu", "paper"), default="cpu")
    ap.add_argument("--policies", default=",".join(POLICIES))
    ap.add_argument("--inference-steps", default="2,5,10,20,100")
    ap.add_argument("--generalisation-is", type=int, default=10)
    ap.add_argument(
        "--variants", default="", help="other task names to evaluate on, e.g. Threading_D1,Threading_D2"
    )
    ap.add_argument("--no-scenes", action="store_true", help="skip the scene-transform evaluation")
    ap.add_argument("--eval-episodes", type=int, default=50)
    ap.add_argument("--eval-batch-size", type=int, default=10)
    ap.add_argument("--eval-seed", type=int, default=1000)
    ap.add_argument(
        "--episode-length", type=int, default=None, help="evaluation episode cap (default: the task's)"
    )
    ap.add_argument("--plot", type=Path, default=None, help="write the IS sweep as a PNG here")
    args = ap.parse_args(argv)

    out = args.output.resolve()
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    env.setdefault("MUJOCO_GL", "egl")
    data, repo_id = out / "data", f"local/{args.task.lower()}_results"
    timings: dict[str, float] = {}

    if not (data / "meta" / "info.json").exists():
        start = time.perf_counter()
        _run(
            [_bin("actionflow-collect"), "--task", args.task, "--episodes", str(args.episodes),
             "--root", str(data), "--repo-id", repo_id, "--seed", str(args.seed)],
            env, out / "logs" / "collect.log",
        )  # fmt: skip
        timings["collect_s"] = time.perf_counter() - start

    sizes = CPU_SIZE if args.preset == "cpu" else PAPER_SIZE
    checkpoints = []
    for policy in args.policies.split(","):
        run = out / "train" / policy
        ckpt = run / "checkpoints" / "last" / "pretrained_model"
        if not ckpt.exists():
            if run.exists():
                import shutil

                shutil.rmtree(run)  # a run interrupted before its checkpoint
            start = time.perf_counter()
            _run(
                [*train_command(), f"--policy.type={policy}", f"--policy.device={args.device}",
                 "--policy.push_to_hub=false", f"--dataset.repo_id={repo_id}", f"--dataset.root={data}",
                 f"--output_dir={run}", f"--steps={args.steps}", f"--save_freq={args.steps}",
                 f"--batch_size={args.batch_size}", "--num_workers=0", "--log_freq=100",
                 "--wandb.enable=false", f"--seed={args.seed}", f"--policy.optimizer_lr={args.lr}",
                 "--policy.scheduler_warmup_steps=100", *COMMON, *sizes[policy]],
                env, out / "logs" / f"train_{policy}.log",
            )  # fmt: skip
            timings[f"train_{policy}_s"] = time.perf_counter() - start
        checkpoints.append(ckpt)

    steps = [int(s) for s in args.inference_steps.split(",")]
    results = {"args": {k: str(v) for k, v in vars(args).items()}, "timings": timings}
    results["is_sweep"] = _sweep(checkpoints, args.task, steps, [], out / "sweep", args, env)
    gen = {}
    for variant in [v for v in args.variants.split(",") if v]:
        gen[variant] = _sweep(
            checkpoints, variant, [args.generalisation_is], [], out / "gen" / variant, args, env
        )
    if not args.no_scenes:
        for i, (name, extra) in enumerate(SCENES.items()):
            gen[name] = _sweep(
                checkpoints, args.task, [args.generalisation_is], extra, out / "gen" / f"scene{i}", args, env
            )
    results["generalisation"] = gen
    (out / "results.json").write_text(json.dumps(results, indent=2))
    print(format_tables(results))
    if args.plot is not None:
        plot_is_sweep(results, args.plot, title=f"{args.task}: success vs inference steps")
        print(f"plot: {args.plot}")
    return 0


def plot_is_sweep(results: dict, path: Path, title: str) -> None:
    """PNG of success rate against IS (log axis), one line per policy."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = results["is_sweep"]
    fig, ax = plt.subplots(figsize=(5, 3.4), dpi=120)
    for policy in dict.fromkeys(r["policy"] for r in rows):
        pts = sorted((r["inference_steps"], r["pc_success"]) for r in rows if r["policy"] == policy)
        ax.plot(*zip(*pts, strict=True), marker="o", label=policy)
    ax.set_xscale("log")
    ax.set_xticks(sorted({r["inference_steps"] for r in rows}))
    ax.get_xaxis().set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.set(xlabel="inference steps IS", ylabel="success %", ylim=(-3, 103), title=title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def format_tables(results: dict) -> str:
    """Markdown: success % per policy x IS, then per policy x evaluation env."""
    rows = results["is_sweep"]
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    steps = sorted({r["inference_steps"] for r in rows})
    cell = {(r["policy"], r["inference_steps"]): r for r in rows}
    lines = ["| policy | " + " | ".join(f"IS={s}" for s in steps) + " |", "| --- |" + " ---: |" * len(steps)]
    for p in policies:
        lines.append(f"| {p} | " + " | ".join(f"{cell[p, s]['pc_success']:.0f}" for s in steps) + " |")
    gen = results.get("generalisation", {})
    if gen:
        names = list(gen)
        gcell = {(name, r["policy"]): r for name in names for r in gen[name]}
        lines += ["", "| policy | " + " | ".join(names) + " |", "| --- |" + " ---: |" * len(names)]
        for p in policies:
            lines.append(f"| {p} | " + " | ".join(f"{gcell[n, p]['pc_success']:.0f}" for n in names) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
