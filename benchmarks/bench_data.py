"""Training data: LeRobotDataset against the in-memory frame source, and ``lerobot-train`` against
``actionflow-train``, on one dataset in one run.

    python benchmarks/bench_data.py --root outputs/demo/data --repo-id local/lift_demo
    python benchmarks/bench_data.py --memory --work /tmp/bench_data_large   # 1,000 x 400 frames

1. **items/s**: both datasets opened with ``actionflow``'s default delta timestamps (2
   observation steps, 16 actions), read through the DataLoader that ``lerobot-train`` builds
   (``EpisodeAwareSampler``, shuffled, default collate, ``num_workers=0``) at ``--batch-size``.
2. **training**: for each policy and size, ``lerobot-train`` (LeRobotDataset,
   ``--lerobot-workers`` loader processes, as the project trained before) and ``actionflow-train``
   (in-memory, ``--num_workers=0``) for ``--steps`` steps at ``--batch-size``; samples/s,
   ``data_s`` and ``updt_s`` are LeRobot's own log figures averaged over the log windows after
   the first (warm-up), and the wall time of each command.
3. ``--memory``: a synthetic dataset of ``--episodes`` x ``--frames`` in the schema (written once
   into ``--work`` through LeRobot's writer: about 20 minutes for 400,000 frames on 2 busy
   cores), opened in a fresh process by each reader after one unmeasured open that fills the
   Arrow cache: resident memory (anonymous and file-backed, from /proc), open time (for the
   in-memory source: LeRobotDataset's open plus the copy into tensors), and the time to the
   first batch of 64 through lerobot-train's DataLoader.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lerobot_actionflow.demo import CPU_POLICY  # noqa: E402

# run_results.py's CPU-size diffusion and its shared history / horizon / executed actions.
COMMON = ["--policy.n_obs_steps=2", "--policy.horizon=16", "--policy.n_action_steps=8"]
POLICIES = {
    "actionflow, main job size": ["--policy.type=actionflow", *CPU_POLICY],
    "actionflow, default size": ["--policy.type=actionflow", *COMMON],
    "diffusion, run_results CPU size": [
        "--policy.type=diffusion",
        "--policy.down_dims=[64,128,256]",
        *COMMON,
    ],
}
LOG = re.compile(r"step:(\S+) .*updt_s:([\d.]+) data_s:([\d.]+) smp/s:([\d.]+)")


def _env() -> dict[str, str]:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    return env


def _open(root: Path, repo_id: str, fast: bool):
    from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_actionflow.data.in_memory import InMemoryLeRobotDataset
    from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig

    meta = LeRobotDatasetMetadata(repo_id, root=root)
    delta = resolve_delta_timestamps(ActionflowConfig(), meta)
    ds = LeRobotDataset(repo_id, root=root, delta_timestamps=delta, return_uint8=True)
    return InMemoryLeRobotDataset(ds) if fast else ds


def _loader(ds, batch_size: int):
    """The training DataLoader of lerobot-train (lerobot/scripts/lerobot_train.py), 0 workers."""
    import torch
    from lerobot.datasets import EpisodeAwareSampler

    sampler = EpisodeAwareSampler(
        ds.meta.episodes["dataset_from_index"],
        ds.meta.episodes["dataset_to_index"],
        episode_indices_to_use=ds.episodes,
        shuffle=True,
        seed=0,
        absolute_to_relative_idx=ds.absolute_to_relative_idx,
    )
    return torch.utils.data.DataLoader(ds, batch_size=batch_size, sampler=sampler, num_workers=0)


def items_per_second(root: Path, repo_id: str, batch_size: int, seconds: float) -> dict:
    """Items/s of both readers through lerobot-train's DataLoader, each timed for ``seconds``."""
    out = {}
    for name, fast in (("LeRobotDataset", False), ("in-memory", True)):
        start = time.perf_counter()
        ds = _open(root, repo_id, fast)
        load_s = time.perf_counter() - start
        loader = _loader(ds, batch_size)
        it, n, start = iter(loader), 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            batch = next(it, None)
            if batch is None:  # next epoch
                it = iter(loader)
                continue
            n += len(batch["index"])
        out[name] = {"items_per_s": n / (time.perf_counter() - start), "items": n, "open_s": load_s}
        out["frames"] = len(ds)
    out["ratio"] = out["in-memory"]["items_per_s"] / out["LeRobotDataset"]["items_per_s"]
    return out


def train_run(cli: str, policy_args: list[str], args, out: Path, workers: int) -> dict:
    """One lerobot-train / actionflow-train run; LeRobot's logged figures after the first window."""
    cmd = (
        [str(Path(sys.executable).with_name("lerobot-train"))]
        if cli == "lerobot-train"
        else [sys.executable, "-m", "lerobot_actionflow.train"]
    )
    cmd += [
        f"--dataset.repo_id={args.repo_id}", f"--dataset.root={args.root}", *policy_args,
        "--policy.device=cpu", "--policy.push_to_hub=false", "--wandb.enable=false",
        f"--output_dir={out}", f"--steps={args.steps}", f"--log_freq={args.log_freq}",
        f"--batch_size={args.batch_size}", f"--num_workers={workers}", "--save_checkpoint=false",
        "--seed=0",
    ]  # fmt: skip
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=_env())
    wall = time.perf_counter() - start
    if proc.returncode:
        raise SystemExit(f"{cli} failed:\n{proc.stderr[-3000:]}")
    rows = [tuple(map(float, m.groups()[1:])) for m in LOG.finditer(proc.stdout + proc.stderr)]
    if len(rows) < 2:
        raise SystemExit(f"{cli}: fewer than 2 log windows in its output; raise --steps")
    upd, data, _ = (sum(col) / (len(rows) - 1) for col in zip(*rows[1:]))
    return {
        "workers": workers,
        "updt_s": upd,
        "data_s": data,
        "step_s": upd + data,
        "samples_per_s": args.batch_size / (upd + data),
        "data_fraction": data / (upd + data),
        "wall_s": wall,
    }


def training(args) -> dict:
    results = {}
    for name, policy_args in POLICIES.items():
        for cli, workers in (("lerobot-train", args.lerobot_workers), ("actionflow-train", 0)):
            tag = re.sub(r"\W+", "_", f"{name}_{cli}")
            print(f"  {name}: {cli} ...", flush=True)
            results.setdefault(name, {})[cli] = train_run(
                cli, policy_args, args, args.work / "train" / tag, workers
            )
    return results


# -- memory on a large synthetic dataset --------------------------------------------------------
def write_large(root: Path, episodes: int, frames: int, tokens: int) -> None:
    import numpy as np
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_actionflow.data.features import schema_features

    features = schema_features(num_tokens=tokens)
    ds = LeRobotDataset.create(repo_id="local/large", fps=20, features=features, root=root, use_videos=False)
    rng = np.random.default_rng(0)
    for e in range(episodes):
        values = {
            k: rng.standard_normal((frames, *ft["shape"])).astype(np.float32) for k, ft in features.items()
        }
        for t in range(frames):
            ds.add_frame({**{k: v[t] for k, v in values.items()}, "task": "synthetic"})
        ds.save_episode()
        if e % 100 == 99:
            print(f"  wrote {e + 1}/{episodes} episodes", flush=True)
    ds.finalize()


MEMORY_PROBE = r"""
import json, sys, time
def rss():
    f = dict(l.split(":", 1) for l in open("/proc/self/status"))
    return {k: int(f[k].split()[0]) / 1024 for k in ("VmRSS", "RssAnon", "RssFile", "VmHWM")}
sys.path.insert(0, sys.argv[4])
from benchmarks.bench_data import _open, _loader
import torch
before = rss()
t0 = time.perf_counter()
ds = _open(sys.argv[1], sys.argv[2], sys.argv[3] == "fast")
load_s = time.perf_counter() - t0
opened = rss()
t1 = time.perf_counter()
batch = next(iter(_loader(ds, 64)))
first_s = time.perf_counter() - t1
print(json.dumps({"load_s": load_s, "copy_s": getattr(ds, "load_s", 0.0), "first_batch_s": first_s,
                  "before_MB": before,
                  "opened_MB": opened, "after_first_batch_MB": rss(), "frames": len(ds),
                  "source_MB": getattr(ds, "nbytes", 0) / 2**20}))
"""


def memory(args) -> dict:
    root = args.work / f"large_{args.episodes}x{args.frames}"
    if not (root / "meta" / "info.json").exists():
        print(f"writing {args.episodes} x {args.frames} frames into {root}", flush=True)
        start = time.perf_counter()
        write_large(root, args.episodes, args.frames, args.tokens)
        print(f"  written in {time.perf_counter() - start:.0f} s", flush=True)
    disk = sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
    out = {"root": str(root), "disk_MB": disk / 2**20}
    # The first open converts the parquet files into the Hugging Face Arrow cache: done once here,
    # unmeasured, so that both readers are timed on a warm cache.
    for name in ("warm-up", "lerobot", "fast"):
        cmd = [sys.executable, "-c", MEMORY_PROBE, str(root), "local/large", name, str(ROOT)]
        proc = subprocess.run(cmd, capture_output=True, text=True, env=_env())
        if proc.returncode:
            raise SystemExit(proc.stderr[-3000:])
        out[name] = json.loads(proc.stdout.strip().splitlines()[-1])
    del out["warm-up"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, help="a LeRobot dataset folder (the main job's: outputs/demo/data)")
    ap.add_argument("--repo-id", default="local/lift_demo")
    ap.add_argument("--batch-size", type=int, default=64)
    ap.add_argument("--seconds", type=float, default=10.0, help="timing per reader for items/s")
    ap.add_argument("--steps", type=int, default=60, help="training steps per run")
    ap.add_argument("--log-freq", type=int, default=20)
    ap.add_argument("--lerobot-workers", type=int, default=1, help="lerobot-train's --num_workers")
    ap.add_argument("--no-train", action="store_true", help="items/s only")
    ap.add_argument("--memory", action="store_true", help="the large synthetic dataset instead")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--frames", type=int, default=400)
    ap.add_argument("--tokens", type=int, default=4, help="poses per frame (EEF + objects)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_data"))
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    load = os.getloadavg()
    print(f"load average at start: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; {os.cpu_count()} CPUs")

    if args.memory:
        result = {"memory": memory(args)}
        print(format_memory(result["memory"]))
    else:
        if args.root is None:
            ap.error("--root is required (or --memory)")
        result = {"items": items_per_second(args.root, args.repo_id, args.batch_size, args.seconds)}
        print(format_items(result["items"], args.batch_size))
        if not args.no_train:
            result["training"] = training(args)
            print(format_training(result["training"], args))
    result["loadavg_end"] = os.getloadavg()
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in result['loadavg_end'])}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))


def format_items(r: dict, batch_size: int) -> str:
    lines = [
        f"items/s through lerobot-train's DataLoader, batch {batch_size}, 0 workers, {r['frames']} frames:",
        "| reader | items/s | open s |",
        "| --- | ---: | ---: |",
    ]
    for name in ("LeRobotDataset", "in-memory"):
        lines.append(f"| {name} | {r[name]['items_per_s']:,.0f} | {r[name]['open_s']:.2f} |")
    lines.append(f"ratio: {r['ratio']:.0f}x")
    return "\n".join(lines)


def format_training(r: dict, args) -> str:
    lines = [
        f"training, batch {args.batch_size}, {args.steps} steps, windows of {args.log_freq} after the first:",
        "| policy | command (workers) | samples/s | data_s | updt_s | data / step | wall s |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name, runs in r.items():
        for cli, m in runs.items():
            lines.append(
                f"| {name} | {cli} ({m['workers']}) | {m['samples_per_s']:.0f} | {m['data_s']:.3f} | "
                f"{m['updt_s']:.3f} | {100 * m['data_fraction']:.0f} % | {m['wall_s']:.0f} |"
            )
        speed = runs["actionflow-train"]["samples_per_s"] / runs["lerobot-train"]["samples_per_s"]
        lines.append(f"| {name} | speed-up | {speed:.1f}x | | | | |")
    return "\n".join(lines)


def format_memory(r: dict) -> str:
    lines = [
        f"large synthetic dataset ({r['fast']['frames']:,} frames, {r['disk_MB']:.0f} MB on disk):",
        "| reader | open s (of which copy) | first batch s | RSS MB (anon + file) after 1st batch "
        "| peak RSS MB | source MB |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name, label in (("lerobot", "LeRobotDataset"), ("fast", "in-memory")):
        m = r[name]
        after = m["after_first_batch_MB"]
        lines.append(
            f"| {label} | {m['load_s']:.1f} ({m['copy_s']:.1f}) | {m['first_batch_s']:.2f} | "
            f"{after['VmRSS']:.0f} ({after['RssAnon']:.0f} + {after['RssFile']:.0f}); "
            f"{m['before_MB']['VmRSS']:.0f} before | {after['VmHWM']:.0f} | {m['source_MB']:.0f} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
