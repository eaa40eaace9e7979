"""The three policies of the results table side by side, in one run: one chunk's latency at
batch 1, training throughput and parameter count.

``actionflow``, ``euclidean_flow`` (LeRobot's diffusion UNet backbone) and LeRobot's
``diffusion`` are built with the sizes that ``run_results.py`` trains (``--preset cpu``: the
small models of benchmarks/RESULTS.md's policy comparison; ``--preset paper``: each policy's
default size) on the Lift workload that they were trained on: ``observation.poses`` (2, 7),
``observation.state`` (11,), ``observation.environment_state`` (9,), action (10,), 2 observation
steps, horizon 16, 8 executed actions. Untrained weights: neither figure depends on them.

- Latency: ``predict_action_chunk`` at batch 1 on inputs already on the device (what runs once
  per chunk in a rollout: observation encoding, IS network calls, sampler arithmetic), eager for
  all three, timed round-robin (one call of each policy in turn) so that load from other processes
  hits them alike; median and p90 of ``--repeats`` calls after ``--warmup``. IS is the number of
  network calls: Euler steps for the flows; DDIM steps for diffusion, DDPM at its 100 training
  steps (``lerobot_actionflow.evaluation.sweep.set_inference_steps``).
- Training: samples per second of ``forward`` + ``backward`` + AdamW step at ``--train-batch``
  (the policies' own losses), the three interleaved step by step.

    python benchmarks/bench_policies.py                      # CPU, and CUDA when present
    python benchmarks/bench_policies.py --device cpu --threads 1 --steps 2 10 --repeats 20
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import time
from datetime import UTC, datetime

import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy
from run_results import COMMON, CPU_SIZE, PAPER_SIZE

from lerobot_actionflow import geometry as g
from lerobot_actionflow.evaluation.sweep import set_inference_steps
from lerobot_actionflow.geometry.se3 import rp_to_pose7
from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig
from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig
from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy
from lerobot_actionflow.schema import ACTION_KEY, ENV_STATE_KEY, POSES_KEY, STATE_KEY, feature_shapes
from lerobot_actionflow.schema.tensors import pose_to_action

POLICIES = {
    "actionflow": (ActionflowConfig, ActionflowPolicy),
    "euclidean_flow": (EuclideanFlowConfig, EuclideanFlowPolicy),
    "diffusion": (DiffusionConfig, DiffusionPolicy),
}
ENTITIES = 2  # Lift: the EEF and the cube
SHAPES = feature_shapes(ENTITIES)


def cli_overrides(args: list[str]) -> dict:
    """``["--policy.dim=64", "--policy.down_dims=[64,128,256]"]`` -> ``{"dim": 64, ...}``: the
    size flags of run_results.py, so that this benchmark times the very models it trains."""
    out = {}
    for arg in args:
        key, _, value = arg.removeprefix("--policy.").partition("=")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value  # a bare string such as backbone=unet
    return out


def build(name: str, preset: str, device: str):
    """An untrained ``name`` policy of the workload, with run_results.py's ``preset`` size."""
    config_cls, policy_cls = POLICIES[name]
    size = (CPU_SIZE if preset == "cpu" else PAPER_SIZE)[name]
    config = config_cls(
        device=device,
        input_features={
            POSES_KEY: PolicyFeature(FeatureType.STATE, SHAPES[POSES_KEY]),
            STATE_KEY: PolicyFeature(FeatureType.STATE, SHAPES[STATE_KEY]),
            ENV_STATE_KEY: PolicyFeature(FeatureType.ENV, SHAPES[ENV_STATE_KEY]),
        },
        output_features={ACTION_KEY: PolicyFeature(FeatureType.ACTION, SHAPES[ACTION_KEY])},
        **cli_overrides(COMMON + size),
    )
    return policy_cls(config).to(device)


def make_batch(batch_size: int, n_obs: int, horizon: int, device: str) -> dict:
    """Random inputs of the workload's shapes: valid poses (unit quaternions), action chunks as
    (position, 6D rotation, gripper); no padding."""
    gen = torch.Generator().manual_seed(0)
    r = g.random_rotation(batch_size, n_obs, ENTITIES, generator=gen)
    batch = {
        POSES_KEY: rp_to_pose7(r, 0.2 * torch.randn(batch_size, n_obs, ENTITIES, 3, generator=gen)),
        STATE_KEY: torch.randn(batch_size, n_obs, *SHAPES[STATE_KEY], generator=gen),
        ENV_STATE_KEY: torch.randn(batch_size, n_obs, *SHAPES[ENV_STATE_KEY], generator=gen),
        ACTION_KEY: pose_to_action(
            g.random_rotation(batch_size, horizon, generator=gen),
            0.1 * torch.randn(batch_size, horizon, 3, generator=gen),
            torch.rand(batch_size, horizon, generator=gen) * 2 - 1,
        ),
        "action_is_pad": torch.zeros(batch_size, horizon, dtype=torch.bool),
    }
    return {k: v.to(device) for k, v in batch.items()}


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def _summary(ms: list[float]) -> dict:
    ms = sorted(ms)
    p90 = ms[math.ceil(0.9 * len(ms)) - 1]  # nearest rank
    return {"median_ms": round(statistics.median(ms), 2), "p90_ms": round(p90, 2)}


@torch.inference_mode()
def time_chunks(policies: dict, obs: dict, steps: int, device: str, warmup: int, repeats: int) -> dict:
    """Latency summary per policy of one ``predict_action_chunk`` with ``steps`` network calls."""
    samplers = {name: set_inference_steps(p, steps) for name, p in policies.items()}
    times = {name: [] for name in policies}
    for i in range(warmup + repeats):
        for name, policy in policies.items():
            policy.reset()
            _sync(device)
            t0 = time.perf_counter()
            policy.predict_action_chunk(obs)
            _sync(device)
            if i >= warmup:
                times[name].append(1e3 * (time.perf_counter() - t0))
    return {name: {"sampler": samplers[name], **_summary(ts)} for name, ts in times.items()}


def train_throughput(policies: dict, batch: dict, device: str, warmup: int, steps: int) -> dict:
    """Samples per second of forward + backward + AdamW step, the policies interleaved."""
    opts = {name: torch.optim.AdamW(p.parameters(), lr=1e-4) for name, p in policies.items()}
    seconds = {name: 0.0 for name in policies}
    for i in range(warmup + steps):
        for name, policy in policies.items():
            policy.train()
            _sync(device)
            t0 = time.perf_counter()
            loss, _ = policy.forward(batch)
            opts[name].zero_grad(set_to_none=True)
            loss.backward()
            opts[name].step()
            _sync(device)
            if i >= warmup:
                seconds[name] += time.perf_counter() - t0
    n = batch[ACTION_KEY].shape[0]
    return {name: round(n * steps / s, 1) for name, s in seconds.items()}


def bench_device(args, device: str) -> dict:
    torch.manual_seed(0)
    policies = {name: build(name, args.preset, device) for name in POLICIES}
    cfg = policies["actionflow"].config
    obs = {
        k: v
        for k, v in make_batch(1, cfg.n_obs_steps, cfg.horizon, device).items()
        if k.startswith("observation.")
    }
    for p in policies.values():
        p.eval()
    result = {
        "parameters": {name: sum(t.numel() for t in p.parameters()) for name, p in policies.items()},
        "latency_batch1": {
            f"IS{k}": time_chunks(policies, obs, k, device, args.warmup, args.repeats) for k in args.steps
        },
    }
    if args.train_steps:
        batch = make_batch(args.train_batch, cfg.n_obs_steps, cfg.horizon, device)
        result["train_samples_per_s"] = train_throughput(
            policies, batch, device, args.train_warmup, args.train_steps
        )
    if device.startswith("cuda"):
        result["gpu"] = torch.cuda.get_device_name()
    return result


def table(results: dict) -> str:
    """Markdown: per device and policy, parameters, latency per IS and training throughput."""
    lines = []
    for device, res in results.items():
        steps = list(res["latency_batch1"])
        lines.append(
            f"| device | policy | parameters | {' | '.join(f'{s} ms' for s in steps)} | train samples/s |"
        )
        lines.append("| --- | --- | ---: |" + " ---: |" * (len(steps) + 1))
        for name in POLICIES:
            lat = " | ".join(f"{res['latency_batch1'][s][name]['median_ms']:.1f}" for s in steps)
            train = res.get("train_samples_per_s", {}).get(name, "-")
            lines.append(f"| {device} | {name} | {res['parameters'][name] / 1e6:.2f}M | {lat} | {train} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto")
    ap.add_argument("--preset", choices=["cpu", "paper"], default="cpu", help="run_results.py's sizes")
    ap.add_argument("--steps", type=int, nargs="+", default=[2, 10], help="inference steps IS")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--threads", type=int, default=None, help="torch intra-op threads (CPU)")
    ap.add_argument("--train-batch", type=int, default=32)
    ap.add_argument("--train-steps", type=int, default=10, help="0 skips the training figure")
    ap.add_argument("--train-warmup", type=int, default=2)
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    devices = ["cpu", "cuda"] if args.device == "auto" else [args.device]
    devices = [d for d in devices if d == "cpu" or torch.cuda.is_available()]
    results = {d: bench_device(args, d) for d in devices}
    print(table(results))
    report = {
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "torch": torch.__version__,
        "cpu": platform.processor() or platform.machine(),
        "cpu_threads": torch.get_num_threads(),
        "preset": args.preset,
        "results": results,
    }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
