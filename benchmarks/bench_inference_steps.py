"""Latency of one action chunk at batch 1 versus the number of inference steps (IS).

Compares, in one process and one run, at equal numbers of network calls (paper, App. E):

- ``diffusion``: LeRobot's Diffusion Policy, DDIM for IS < 100, DDPM at IS = 100
  (= ``num_train_timesteps``);
- ``ef-unet``: ``euclidean_flow`` with the same LeRobot UNet (same ``down_dims``), IS Euler steps;
- ``ef-transformer``: ``euclidean_flow`` with the Diffusion-Policy-style transformer (8 layers,
  4 heads, 256 wide), IS Euler steps.

Workload (DESIGN.md section 9): state input (``observation.state`` (11,),
``observation.environment_state`` (9,)), 2 observation steps, horizon 16, action (10,). Untrained
weights: latency does not depend on them. Timed: ``policy.predict_action_chunk`` on normalised
inputs already on the device (encoding + IS network calls + sampler arithmetic), median over
``--repeats`` calls after ``--warmup``, the three policies interleaved, CUDA synchronised.

    python benchmarks/bench_inference_steps.py                       # CPU, and CUDA if present
    python benchmarks/bench_inference_steps.py --down-dims 64,128,256 --repeats 3 --json out.json
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from datetime import UTC, datetime

import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

from lerobot_actionflow.evaluation.sweep import set_inference_steps
from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig
from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy
from lerobot_actionflow.schema import ACTION_DIM, ACTION_KEY, ENV_STATE_KEY, POSE9_DIM, STATE_DIM, STATE_KEY

STATE, ENV, ACTION = STATE_DIM, POSE9_DIM, ACTION_DIM  # one object token
N_OBS, HORIZON, N_ACTION = 2, 16, 8
POLICIES = ("diffusion", "ef-unet", "ef-transformer")


def _features():
    inputs = {
        STATE_KEY: PolicyFeature(FeatureType.STATE, (STATE,)),
        ENV_STATE_KEY: PolicyFeature(FeatureType.ENV, (ENV,)),
    }
    return inputs, {ACTION_KEY: PolicyFeature(FeatureType.ACTION, (ACTION,))}


def build(name: str, device: str, down_dims: tuple[int, ...]):
    """An untrained policy of the benchmark's workload, in eval mode on ``device``."""
    inputs, outputs = _features()
    common = dict(
        device=device,
        n_obs_steps=N_OBS,
        horizon=HORIZON,
        n_action_steps=N_ACTION,
        input_features=inputs,
        output_features=outputs,
    )
    if name == "diffusion":
        policy = DiffusionPolicy(DiffusionConfig(down_dims=down_dims, **common))
    elif name == "ef-unet":
        policy = EuclideanFlowPolicy(EuclideanFlowConfig(backbone="unet", down_dims=down_dims, **common))
    elif name == "ef-transformer":
        policy = EuclideanFlowPolicy(EuclideanFlowConfig(backbone="transformer", **common))
    else:
        raise ValueError(f"unknown policy {name!r}: expected one of {POLICIES}")
    return policy.to(device).eval()


def time_chunk(policy, batch: dict, device: str) -> float:
    """Milliseconds of one ``policy.predict_action_chunk(batch)`` (fresh queues)."""
    policy.reset()
    if device.startswith("cuda"):
        torch.cuda.synchronize()
    start = time.perf_counter()
    policy.predict_action_chunk(batch)
    if device.startswith("cuda"):
        torch.cuda.synchronize()
    return 1000 * (time.perf_counter() - start)


def run(devices: list[str], steps: list[int], down_dims, warmup: int, repeats: int) -> list[dict]:
    """Per device and IS, the three policies are timed round-robin (one call each per repeat), so
    that load from other processes hits them alike; the median of ``repeats`` calls is kept."""
    rows = []
    for device in devices:
        batch = {
            STATE_KEY: torch.randn(1, N_OBS, STATE, device=device),
            ENV_STATE_KEY: torch.randn(1, N_OBS, ENV, device=device),
        }
        torch.manual_seed(0)
        policies = {name: build(name, device, down_dims) for name in POLICIES}
        with torch.inference_mode():
            for k in steps:
                samplers = {name: set_inference_steps(p, k) for name, p in policies.items()}
                times: dict[str, list[float]] = {name: [] for name in POLICIES}
                for i in range(warmup + repeats):
                    for name, policy in policies.items():
                        ms = time_chunk(policy, batch, device)
                        if i >= warmup:
                            times[name].append(ms)
                for name, policy in policies.items():
                    row = dict(
                        device=device,
                        policy=name,
                        params=sum(p.numel() for p in policy.parameters()),
                        steps=k,
                        sampler=samplers[name],
                        ms=statistics.median(times[name]),
                    )
                    rows.append(row)
                    print(
                        f"  {device:5s} {name:15s} IS={k:<4d} {row['sampler']:18s} {row['ms']:10.2f} ms",
                        file=sys.stderr,
                    )
        del policies
        if device.startswith("cuda"):
            torch.cuda.empty_cache()
    return rows


def table(rows: list[dict]) -> str:
    """Markdown: one line per (device, IS), milliseconds and ratios to diffusion."""
    ms = {(r["device"], r["policy"], r["steps"]): r["ms"] for r in rows}
    lines = [
        "| device | IS | diffusion ms (sampler) | ef-unet ms | ef-transformer ms "
        "| ef-unet / diffusion | ef-transformer / diffusion |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        if r["policy"] != "diffusion":
            continue
        d, k = r["device"], r["steps"]
        u, t = ms[(d, "ef-unet", k)], ms[(d, "ef-transformer", k)]
        lines.append(
            f"| {d} | {k} | {r['ms']:.1f} ({r['sampler']}) | {u:.1f} | {t:.1f} "
            f"| {u / r['ms']:.2f} | {t / r['ms']:.2f} |"
        )
    params = {r["policy"]: r["params"] for r in rows}
    lines.append("")
    lines.append("Parameters: " + ", ".join(f"{k} {v / 1e6:.1f}M" for k, v in params.items()))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, nargs="+", default=[2, 5, 10, 20, 100])
    ap.add_argument("--devices", nargs="+", default=None, help="default: cpu, and cuda when present")
    ap.add_argument(
        "--down-dims",
        default="512,1024,2048",
        help="UNet widths for diffusion and ef-unet (LeRobot's default, 250M params; 64,128,256 is small)",
    )
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    ap.add_argument("--json", default=None, help="also write the results here")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    devices = args.devices or (["cpu", "cuda"] if torch.cuda.is_available() else ["cpu"])
    down_dims = tuple(int(x) for x in args.down_dims.split(","))
    rows = run(devices, args.steps, down_dims, args.warmup, args.repeats)
    result = {
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "command": " ".join(["python", "benchmarks/bench_inference_steps.py", *(argv or sys.argv[1:])]),
        "torch": torch.__version__,
        "cpu": platform.processor() or platform.machine(),
        "cpu_threads": torch.get_num_threads(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "down_dims": list(down_dims),
        "warmup": args.warmup,
        "repeats": args.repeats,
        "rows": rows,
    }
    print(table(rows))
    print(json.dumps(result, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)
    return result


if __name__ == "__main__":
    main()
