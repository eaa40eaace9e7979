"""The paper's Fig. 12 protocol on MugHang: pose tokens against point clouds, training placement
against a moved hanger.

Stages (each skipped when its output exists, so an interrupted run continues where it stopped):

1. ``actionflow-collect --point-cloud``: ``--episodes`` expert demonstrations of ``MugHang_D0``
   (the hanger in one place) with ``observation.point_cloud`` (``--points`` points): one
   dataset, the same demonstrations for every policy;
2. ``actionflow-train`` of three policies on it, the same steps, batch, history and horizon
   (a checkpoint every ``--save-every`` steps; an interrupted run resumes from its last one):

   - ``actionflow_pose``: ActionFlow with the mug and hanger pose tokens (no cloud);
   - ``actionflow_pc``: ActionFlow with point-cloud group tokens, reading only the EEF row of
     ``observation.poses`` (``pose_entities=[0]``): mug and hanger only through the cloud;
   - ``euclidean_flow_pc``: ``euclidean_flow`` (UNet) with the PointNet cloud feature, the EEF
     and gripper state, and no object poses (``use_environment_state=false``);

3. ``lerobot_actionflow.evaluation.sweep`` of each policy on ``MugHang_D0`` and
   ``MugHang_Moved`` (the hanger on either side, turned), ``--eval-episodes`` per cell (50 in
   the paper's protocol), the same evaluation seeds in every cell; point clouds rendered by the
   env for the point-cloud policies.

Writes ``<output>/fig12_results.json`` (cells, timings, arguments) and
``<output>/fig12_table.md`` (success % per policy and variant), and prints the table. Each save
merges into the JSON under a file lock, so runs of disjoint ``--policies`` on one ``--output``
(after its collection) can go side by side.

``--policies`` also accepts the point-token ablations of ``actionflow_pc`` (not run by default):
``actionflow_pc_g16`` / ``actionflow_pc_g64`` (G point tokens instead of ``--groups``) and
``actionflow_pc_k1`` / ``actionflow_pc_k32`` (k points per group instead of ``--group-size``;
k = 1 is bare points: each token carries only its position, no local geometry), and
``actionflow_pc_m128`` (the first 128 of the recorded ``--points`` FPS-ordered points, which are
their 128-point FPS subsample). ``--variants MugHang_D0`` evaluates the training placements only.

    python benchmarks/fig12_mug_hang.py --output outputs/fig12
    # tiny check that every stage runs (minutes on a CPU):
    python benchmarks/fig12_mug_hang.py --output /tmp/fig12_tiny --episodes 1 --steps 2 \\
        --points 64 --eval-episodes 1 --episode-length 10 --tiny-models
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from train_runs import final_checkpoint, run_logged, train_run

from lerobot_actionflow.data.staging import exclusive_lock
from lerobot_actionflow.schema import POINT_CLOUD_KEY

TRAIN_TASK = "MugHang_D0"
VARIANTS = ("MugHang_D0", "MugHang_Moved")
COMMON = ["--policy.n_obs_steps=2", "--policy.horizon=16", "--policy.n_action_steps=8"]
AF_CPU = ["--policy.dim=64", "--policy.num_layers=2", "--policy.num_heads=4", "--policy.head_dim=16"]
AF_TINY = ["--policy.dim=32", "--policy.num_layers=1", "--policy.num_heads=2", "--policy.head_dim=8"]
EF_CPU = ["--policy.backbone=unet", "--policy.down_dims=[64,128,256]"]
EF_TINY = ["--policy.backbone=unet", "--policy.down_dims=[16,32,64]", "--policy.n_groups=8"]
PC = [f"--policy.point_cloud_key={POINT_CLOUD_KEY}"]
FIGURE = ("actionflow_pose", "actionflow_pc", "euclidean_flow_pc")
#: ``actionflow_pc`` ablations: name suffix -> the one ``--policy.point_cloud_<knob>`` it changes:
#: G point tokens (``groups``), k points per group (``group_size``), or the cloud's first N of
#: its M FPS-ordered points (``prefix``, below ``--points``).
POINT_TOKEN_ABLATIONS = {
    "g16": ("groups", 16),
    "g64": ("groups", 64),
    "k1": ("group_size", 1),
    "k32": ("group_size", 32),
    "m128": ("prefix", 128),
}


def policies(args) -> dict[str, dict]:
    """Name -> ``{"type", "args", "point_cloud"}`` of the three policies of the figure (:data:`FIGURE`)
    and of the point-token ablations."""
    af = AF_TINY if args.tiny_models else AF_CPU
    ef = EF_TINY if args.tiny_models else EF_CPU

    def actionflow_pc(**knobs) -> dict:
        knobs = {"groups": args.groups, "group_size": args.group_size, **knobs}
        tokens = [f"--policy.point_cloud_{knob}={value}" for knob, value in knobs.items()]
        return {
            "type": "actionflow",
            "args": [*af, *PC, *tokens, "--policy.pose_entities=[0]"],
            "point_cloud": True,
        }

    table = {
        "actionflow_pose": {"type": "actionflow", "args": af, "point_cloud": False},
        "actionflow_pc": actionflow_pc(),
        "euclidean_flow_pc": {
            "type": "euclidean_flow",
            "args": [*ef, *PC, "--policy.use_environment_state=false"],
            "point_cloud": True,
        },
    }
    for suffix, (knob, value) in POINT_TOKEN_ABLATIONS.items():
        table[f"actionflow_pc_{suffix}"] = actionflow_pc(**{knob: value})
    return table


def merge_save(path: Path, results: dict) -> dict:
    """Merge ``results`` into the JSON at ``path`` (timings and cells per policy and variant; ours
    win) under ``<path>.lock``, write it atomically, and return the merged content."""
    with exclusive_lock(path.with_name(path.name + ".lock")):
        merged = json.loads(path.read_text()) if path.exists() else {"timings": {}, "cells": {}}
        merged["args"] = results["args"]
        merged["timings"].update(results["timings"])
        for name, row in results["cells"].items():
            merged["cells"].setdefault(name, {}).update(row)
        tmp = path.with_name(f".{path.name}.{os.getpid()}")
        tmp.write_text(json.dumps(merged, indent=2))
        os.replace(tmp, path)
    return merged


def format_table(cells: dict, names: list[str], episodes: int) -> str:
    """Markdown: success % of each policy (rows) on each variant (columns)."""
    lines = [
        f"| policy | {' | '.join(VARIANTS)} |",
        "| --- |" + " ---: |" * len(VARIANTS),
    ]
    for name in names:
        vals = []
        for variant in VARIANTS:
            row = cells.get(name, {}).get(variant)
            vals.append("-" if row is None else f"{row['pc_success']:.0f} ({row['n_episodes']})")
        lines.append(f"| {name} | {' | '.join(vals)} |")
    lines.append(f"\nsuccess % (episodes); {episodes} episodes per cell requested")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--output", type=Path, required=True)
    ap.add_argument("--episodes", type=int, default=50, help="expert demonstrations of MugHang_D0")
    ap.add_argument("--points", type=int, default=512, help="M, points per cloud")
    ap.add_argument("--cloud-image-size", type=int, default=128, help="depth image size per camera")
    ap.add_argument("--groups", type=int, default=32, help="actionflow_pc: G point tokens")
    ap.add_argument("--group-size", type=int, default=16, help="actionflow_pc: k points per token")
    ap.add_argument("--seed", type=int, default=0, help="collection and training seed")
    ap.add_argument("--steps", type=int, default=20000, help="training steps, every policy")
    ap.add_argument(
        "--save-every", type=int, default=1000, help="checkpoint interval (an interrupted run resumes)"
    )
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--device", default="cpu", help="training device")
    ap.add_argument("--tiny-models", action="store_true", help="very small networks (a smoke run)")
    ap.add_argument(
        "--policies",
        default="",
        help="comma-separated policies (default: the figure's three; see the docstring)",
    )
    ap.add_argument("--inference-steps", type=int, default=10, help="IS of the evaluation")
    ap.add_argument("--eval-episodes", type=int, default=50)
    ap.add_argument("--eval-batch-size", type=int, default=10)
    ap.add_argument("--eval-seed", type=int, default=1000)
    ap.add_argument(
        "--eval-async",
        action="store_true",
        help="one process per env (about 1.3 GB each) instead of sync envs",
    )
    ap.add_argument("--episode-length", type=int, default=None, help="evaluation cap (default: the task's)")
    ap.add_argument(
        "--variants",
        default=",".join(VARIANTS),
        help="comma-separated evaluation tasks (the ablations need only MugHang_D0)",
    )
    args = ap.parse_args(argv)
    variants = [v for v in args.variants.split(",") if v]
    if not variants or set(variants) - set(VARIANTS):
        unknown = sorted(set(variants) - set(VARIANTS)) or "none given"
        raise SystemExit(f"--variants: unknown tasks {unknown}; choose from {list(VARIANTS)}")

    out = args.output.resolve()
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    env.setdefault("MUJOCO_GL", "egl")
    results_path = out / "fig12_results.json"
    results = json.loads(results_path.read_text()) if results_path.exists() else {"timings": {}, "cells": {}}
    results["args"] = {k: str(v) for k, v in vars(args).items()}
    timings, cells = results["timings"], results["cells"]

    def save() -> None:
        merge_save(results_path, results)

    data, repo_id = out / "data", "local/mug_hang_fig12"
    cloud_args = [
        "--point-cloud-points",
        str(args.points),
        "--point-cloud-image-size",
        str(args.cloud_image_size),
    ]
    if not (data / "meta" / "info.json").exists():
        timings["collect_s"] = run_logged(
            [sys.executable, "-m", "lerobot_actionflow.data.collect", "--task", TRAIN_TASK,
             "--episodes", str(args.episodes), "--root", str(data), "--repo-id", repo_id,
             "--seed", str(args.seed), "--no-progress", "--point-cloud", *cloud_args],
            env, out / "logs" / "collect.log",
        )  # fmt: skip
        save()

    table = policies(args)
    names = [n for n in args.policies.split(",") if n] or list(FIGURE)
    unknown = sorted(set(names) - set(table))
    if unknown:
        raise SystemExit(f"unknown policies {unknown}; choose from {sorted(table)}")
    for suffix, (knob, value) in POINT_TOKEN_ABLATIONS.items():
        if f"actionflow_pc_{suffix}" in names and knob == "prefix" and value >= args.points:
            raise SystemExit(
                f"actionflow_pc_{suffix} reads the first {value} points of each cloud: "
                f"it needs --points > {value}, got {args.points}"
            )
    for name in names:
        spec = table[name]
        run = out / "train" / name
        ckpt = final_checkpoint(run, args.steps)
        if not ckpt.exists():
            resumed = (run / "checkpoints" / "last").exists()
            save_freq = min(args.save_every, args.steps)
            wall = train_run(
                run,
                [f"--policy.type={spec['type']}", f"--policy.device={args.device}",
                 "--policy.push_to_hub=false", f"--dataset.repo_id={repo_id}", f"--dataset.root={data}",
                 f"--output_dir={run}", f"--steps={args.steps}", f"--save_freq={save_freq}",
                 f"--batch_size={args.batch_size}", "--num_workers=0", "--log_freq=100",
                 "--wandb.enable=false", f"--seed={args.seed}", f"--policy.optimizer_lr={args.lr}",
                 f"--policy.scheduler_warmup_steps={min(100, args.steps)}", *COMMON, *spec["args"]],
                args.steps, out / "logs" / f"train_{name}.log", env,
            )  # fmt: skip
            timings[f"train_{name}_{'last_part_' if resumed else ''}s"] = wall
            save()
        for variant in variants:
            if variant in cells.get(name, {}):
                continue
            cell_dir = out / "eval" / name / variant
            env_cloud = (
                ["--env.point_cloud=true", f"--env.point_cloud_points={args.points}",
                 f"--env.point_cloud_image_size={args.cloud_image_size}"]
                if spec["point_cloud"] else []
            )  # fmt: skip
            timings[f"eval_{name}_{variant}_s"] = run_logged(
                [sys.executable, "-m", "lerobot_actionflow.evaluation.sweep", f"--checkpoints=[{ckpt}]",
                 "--env.type=actionflow", f"--env.task={variant}", *env_cloud,
                 *([f"--env.episode_length={args.episode_length}"] if args.episode_length else []),
                 f"--inference_steps=[{args.inference_steps}]", f"--eval.n_episodes={args.eval_episodes}",
                 f"--eval.batch_size={min(args.eval_batch_size, args.eval_episodes)}",
                 f"--eval.use_async_envs={str(args.eval_async).lower()}",
                 f"--seed={args.eval_seed}", "--device=cpu", f"--output_dir={cell_dir}",
                 "--guide_to_previous_chunk=false"],  # the protocol of the stored cells
                env, out / "logs" / f"eval_{name}_{variant}.log",
            )  # fmt: skip
            (row,) = json.loads((cell_dir / "sweep_results.json").read_text())
            cells.setdefault(name, {})[variant] = row
            save()

    cells = merge_save(results_path, results)["cells"]
    text = format_table(cells, [n for n in table if n in cells], args.eval_episodes)
    (out / "fig12_table.md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
