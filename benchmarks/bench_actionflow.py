"""ActionFlow speed: one chunk's latency at batch 1, training throughput, parameter count.

Prints one JSON object. Default model: 4 IPA layers, history 2, horizon 16, 5 entities (EEF +
4 objects), state scalars, no images (``--image`` adds an 80x80 wrist camera). Latency is
measured for K in {2, 4, 10} eagerly and with the fast-inference option
(``compile_sampler``: ``torch.compile`` of the whole K-step sampler; on CUDA its
"reduce-overhead" mode replays CUDA graphs, on the CPU the weights are frozen into the graph),
timed round-robin so that both see the same load (this matters on shared machines).

    python benchmarks/bench_actionflow.py                 # CPU, and CUDA when present
    python benchmarks/bench_actionflow.py --device cpu --no-fast --repeats 50
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time

import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow import geometry as g
from lerobot_actionflow.flow import se3 as se3_flow
from lerobot_actionflow.geometry.se3 import rp_to_pose7
from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig
from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
from lerobot_actionflow.schema import (
    ACTION_DIM,
    ACTION_KEY,
    POSE7_DIM,
    POSES_KEY,
    STATE_DIM,
    STATE_KEY,
    image_key,
)
from lerobot_actionflow.schema.tensors import pose_to_action


def make_config(args, device: str, fast: bool) -> ActionflowConfig:
    inputs = {
        POSES_KEY: PolicyFeature(FeatureType.STATE, (args.entities, POSE7_DIM)),
        STATE_KEY: PolicyFeature(FeatureType.STATE, (STATE_DIM,)),
    }
    if args.image:
        inputs[image_key("wrist")] = PolicyFeature(FeatureType.VISUAL, (3, 80, 80))
    return ActionflowConfig(
        n_obs_steps=args.n_obs_steps,
        horizon=args.horizon,
        num_layers=args.layers,
        input_features=inputs,
        output_features={ACTION_KEY: PolicyFeature(FeatureType.ACTION, (ACTION_DIM,))},
        device=device,
        compile_sampler=fast,  # CPU: frozen weights + C++ wrapper; CUDA: CUDA graphs
        compile_mode="reduce-overhead",
    )


def make_batch(cfg: ActionflowConfig, batch_size: int, device: str) -> dict:
    gen = torch.Generator().manual_seed(0)
    n = cfg.input_features[POSES_KEY].shape[0]
    r = g.random_rotation(batch_size, cfg.n_obs_steps, n, generator=gen)
    p = 0.2 * torch.randn(batch_size, cfg.n_obs_steps, n, 3, generator=gen)
    batch = {
        POSES_KEY: rp_to_pose7(r, p),
        STATE_KEY: torch.randn(batch_size, cfg.n_obs_steps, STATE_DIM, generator=gen),
        ACTION_KEY: pose_to_action(
            g.random_rotation(batch_size, cfg.horizon, generator=gen),
            0.1 * torch.randn(batch_size, cfg.horizon, 3, generator=gen),
            torch.rand(batch_size, cfg.horizon, generator=gen) * 2 - 1,
        ),
    }
    for key, ft in cfg.image_features.items():
        batch[key] = torch.rand(batch_size, cfg.n_obs_steps, *ft.shape, generator=gen)
    return {k: v.to(device) for k, v in batch.items()}


def _sync(device: str) -> None:
    if device == "cuda":
        torch.cuda.synchronize()


def time_chunks(policies: dict, batch, k: int, device: str, warmup: int, repeats: int) -> dict:
    """Median / p90 latency of ``predict_action_chunk`` for each policy, timed round-robin (one
    call of each in turn) so that they all see the same machine load."""
    obs = {key: v for key, v in batch.items() if key != ACTION_KEY}
    first = {}
    for mode, policy in policies.items():
        t0 = time.perf_counter()
        policy.predict_action_chunk(obs, num_inference_steps=k)
        _sync(device)
        first[mode] = time.perf_counter() - t0
        for _ in range(warmup):
            policy.predict_action_chunk(obs, num_inference_steps=k)
    _sync(device)
    times = {mode: [] for mode in policies}
    for _ in range(repeats):
        for mode, policy in policies.items():
            t0 = time.perf_counter()
            policy.predict_action_chunk(obs, num_inference_steps=k)
            _sync(device)
            times[mode].append((time.perf_counter() - t0) * 1e3)
    out = {}
    for mode, ts in times.items():
        ts.sort()
        out[mode] = {
            "median_ms": round(statistics.median(ts), 3),
            "p90_ms": round(ts[int(0.9 * (len(ts) - 1))], 3),
            "first_call_s": round(first[mode], 2),
        }
    return out


def train_throughput(args, device: str) -> float:
    torch.manual_seed(0)
    cfg = make_config(args, device, fast=False)
    policy = ActionflowPolicy(cfg).to(device).train()
    opt = torch.optim.AdamW(policy.parameters(), lr=1e-4)
    batch = make_batch(cfg, args.train_batch, device)
    for step in range(args.train_warmup + args.train_steps):
        if step == args.train_warmup:
            _sync(device)
            t0 = time.perf_counter()
        loss, _ = policy.forward(batch)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    _sync(device)
    return args.train_batch * args.train_steps / (time.perf_counter() - t0)


def bench_device(args, device: str) -> dict:
    result = {"latency_batch1": {}}
    policies = {}
    for fast in (False, True) if args.fast else (False,):
        torch.manual_seed(0)  # same weights for both
        cfg = make_config(args, device, fast)
        policies["fast" if fast else "eager"] = ActionflowPolicy(cfg).to(device).eval()
    batch = make_batch(policies["eager"].config, 1, device)
    for k in args.steps:
        for mode, timing in time_chunks(policies, batch, k, device, args.warmup, args.repeats).items():
            result["latency_batch1"][f"{mode}_K{k}"] = timing
    # Same weights and the same noise: the fast path must give the eager actions.
    cfg = policies["eager"].config
    noise = se3_flow.draw_local_noise(
        1, cfg.horizon, cfg.noise_sigma, generator=torch.Generator().manual_seed(1)
    )
    noise = se3_flow.LocalNoise(noise.r.to(device), noise.p.to(device), noise.g.to(device))
    obs = {key: v for key, v in batch.items() if key != ACTION_KEY}
    chunks = {mode: p.predict_action_chunk(obs, noise=noise).cpu() for mode, p in policies.items()}
    result["parameters"] = sum(p.numel() for p in policies["eager"].parameters())
    if "fast" in chunks:
        result["fast_vs_eager_max_abs_diff"] = float((chunks["fast"] - chunks["eager"]).abs().max())
    if args.train_steps:
        result["train_samples_per_s"] = round(train_throughput(args, device), 1)
    if device == "cuda":
        result["gpu"] = torch.cuda.get_device_name()
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto")
    ap.add_argument("--steps", type=int, nargs="+", default=[2, 4, 10], help="K values")
    ap.add_argument("--entities", type=int, default=5)
    ap.add_argument("--n-obs-steps", type=int, default=2)
    ap.add_argument("--horizon", type=int, default=16)
    ap.add_argument("--layers", type=int, default=4)
    ap.add_argument("--image", action="store_true", help="add an 80x80 wrist camera (ResNet18)")
    ap.add_argument("--repeats", type=int, default=100)
    ap.add_argument("--warmup", type=int, default=10)
    ap.add_argument("--threads", type=int, default=None, help="torch intra-op threads (CPU)")
    ap.add_argument("--no-fast", dest="fast", action="store_false", help="skip the compiled sampler")
    ap.add_argument("--train-batch", type=int, default=64)
    ap.add_argument("--train-steps", type=int, default=10)
    ap.add_argument("--train-warmup", type=int, default=3)
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    devices = ["cpu", "cuda"] if args.device == "auto" else [args.device]
    devices = [d for d in devices if d == "cpu" or torch.cuda.is_available()]
    report = {
        "date": time.strftime("%Y-%m-%d"),
        "torch": torch.__version__,
        "cpu": platform.processor() or platform.machine(),
        "cpu_threads": torch.get_num_threads(),
        "config": {k: getattr(args, k) for k in ("entities", "n_obs_steps", "horizon", "layers", "image")},
        "results": {d: bench_device(args, d) for d in devices},
    }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
