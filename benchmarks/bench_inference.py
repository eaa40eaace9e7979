"""Deployable inference: time from process start to the first action, and steady-state chunk
latency, for ActionFlow eager / ``torch.compile`` / exported (AOTInductor) and LeRobot's
``diffusion`` (default size and the small UNet), in one run, one fresh process per variant.

Workload: ActionFlow's default size (width 128, 4 IPA layers, 8 heads) on
``bench_actionflow.py``'s pose workload (5 entities: the EEF and 4 objects, history 2, horizon
16, state scalars, no images), untrained weights (latency does not depend on them), saved as a
checkpoint and exported with ``actionflow-export --steps <K...>`` once (reused on later runs; the
export time is printed when it runs). Diffusion: ``bench_policies.py``'s ``diffusion`` with
``run_results.py``'s sizes (``paper`` = LeRobot's default UNet, ``cpu`` = ``down_dims``
64,128,256) on its Lift workload, built in the worker; IS = DDIM steps
(``set_inference_steps``).

Each worker process measures, from its own start (the parent's spawn time):

- ``import_s``: torch, LeRobot and this package imported;
- ``first_action_s``: the policy loaded (``from_pretrained``) and the first ``select_action``
  returned (one chunk at the config's K = 4; for ``compile`` this includes compiling it);
- per K / IS: the median and p90 of ``--repeats`` ``predict_action_chunk`` calls at batch 1
  after ``--warmup`` calls (``first_call_s``: the first call at that K, a compile for
  ``compile``);
- for ActionFlow, per K also the guided chunk (``K<k>_guided``): what ``guide_to_previous_chunk``
  (the default) samples for every chunk after an episode's first, and LeRobot's RTC engine for
  every chunk, ``predict_action_chunk(obs, inference_delay=0, prev_chunk_left_over=leftover)``
  with the tail past ``n_action_steps`` of a plain chunk as the leftover; the exported variant
  serves it from the guided artefact (``actionflow-export`` makes both).

    python benchmarks/bench_inference.py                          # CPU, 2 threads
    python benchmarks/bench_inference.py --variants exported eager --steps 4 --repeats 50
    python benchmarks/bench_inference.py --device cuda            # where a GPU exists
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ACTIONFLOW_VARIANTS = ("eager", "compile", "exported")
DIFFUSION_VARIANTS = {"diffusion_default": "paper", "diffusion_small": "cpu"}


def _summary(ms: list[float]) -> dict:
    ms = sorted(ms)
    return {
        "median_ms": round(statistics.median(ms), 3),
        "p90_ms": round(ms[math.ceil(0.9 * len(ms)) - 1], 3),
    }


# -- worker ---------------------------------------------------------------------------------------
def worker(args) -> dict:
    """One variant in this (fresh) process; returns its figures."""
    import torch

    torch.set_num_threads(args.threads)
    sys.path.insert(0, str(HERE))
    from bench_actionflow import make_batch
    from bench_policies import build
    from bench_policies import make_batch as make_lift_batch

    from lerobot_actionflow.evaluation.sweep import set_inference_steps
    from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
    from lerobot_actionflow.schema import ACTION_KEY

    out = {"import_s": round(time.time() - args.spawn_time, 3), "threads": torch.get_num_threads()}
    device = args.device

    def sync():
        if device == "cuda":
            torch.cuda.synchronize()

    if args.worker in ACTIONFLOW_VARIANTS:
        from lerobot.configs.policies import PreTrainedConfig

        config = PreTrainedConfig.from_pretrained(args.checkpoint)
        config.device = device
        config.compile_sampler = args.worker == "compile"
        policy = ActionflowPolicy.from_pretrained(args.checkpoint, config=config)
        if args.worker != "exported":
            policy.exported_samplers = None
        elif not policy.exported_samplers or not policy.exported_samplers.keys():
            raise SystemExit(f"no exported sampler was accepted for {args.checkpoint} (see the log above)")
        else:
            out["exported"] = [key.describe() for key in policy.exported_samplers.keys()]
        obs = {k: v for k, v in make_batch(policy.config, 1, device).items() if k != ACTION_KEY}

        def set_steps(k):
            return lambda o: policy.predict_action_chunk(o, num_inference_steps=k)

        def set_guided_steps(k):
            with torch.inference_mode():
                leftover = policy.predict_action_chunk(obs, num_inference_steps=k)[
                    :, policy.config.n_action_steps :
                ]
            return lambda o: policy.predict_action_chunk(
                o, num_inference_steps=k, inference_delay=0, prev_chunk_left_over=leftover
            )
    else:
        policy = build("diffusion", DIFFUSION_VARIANTS[args.worker], device).eval()
        batch = make_lift_batch(1, policy.config.n_obs_steps, policy.config.horizon, device)
        obs = {k: v for k, v in batch.items() if k not in (ACTION_KEY, "action_is_pad")}

        def set_steps(k):
            set_inference_steps(policy, k)
            return policy.predict_action_chunk

    with torch.inference_mode():
        policy.reset()
        policy.select_action({k: v[:, -1] for k, v in obs.items()})
        sync()
        out["first_action_s"] = round(time.time() - args.spawn_time, 3)
        out["parameters"] = sum(p.numel() for p in policy.parameters())
        cells = [(f"K{k}", k, set_steps) for k in args.steps]
        if args.worker in ACTIONFLOW_VARIANTS:
            cells += [(f"K{k}_guided", k, set_guided_steps) for k in args.steps]
        for name, k, make_chunk in cells:
            chunk = make_chunk(k)
            t0 = time.perf_counter()
            chunk(obs)
            sync()
            first = time.perf_counter() - t0
            for _ in range(args.warmup):
                chunk(obs)
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                chunk(obs)
                sync()
                times.append(1e3 * (time.perf_counter() - t0))
            out[name] = {"first_call_s": round(first, 3), **_summary(times)}
            if args.worker == "exported" and name == f"K{k}":
                out[name]["package_only"] = _package_only(policy, obs, k, args.repeats)
    return out


def _package_only(policy, obs: dict, k: int, repeats: int) -> dict:
    """The artefact's own call on prepared inputs: what ``predict_action_chunk`` adds around it
    (input checks, noise drawing, the staleness check) is the difference."""
    from lerobot_actionflow.flow import se3 as se3_flow
    from lerobot_actionflow.policies.exported import ArtefactKey
    from lerobot_actionflow.schema import POSES_KEY, STATE_KEY

    cfg = policy.config
    checked = policy.check_observation(obs)
    noise = se3_flow.draw_local_noise(1, cfg.horizon, cfg.noise_sigma, cfg.noise_rotation, cfg.noise_kappa)
    runner = policy.exported_samplers._runners[ArtefactKey("cpu", k, 1)]
    inputs = [checked[POSES_KEY], checked[STATE_KEY], noise.r, noise.p, noise.g]
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        runner(inputs)
        times.append(1e3 * (time.perf_counter() - t0))
    return _summary(times)


# -- parent ---------------------------------------------------------------------------------------
def make_checkpoint(workdir: Path, device: str, steps: list[int]) -> tuple[Path, dict]:
    """The default-size checkpoint with artefacts for every K, plain and guided (exported when
    missing)."""
    import torch

    sys.path.insert(0, str(HERE))
    from bench_actionflow import make_config

    from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
    from lerobot_actionflow.policies.exported import EXPORT_DIR, artefact_name

    ckpt = workdir / "pretrained_model"
    if not (ckpt / "model.safetensors").exists():
        torch.manual_seed(0)
        workload = argparse.Namespace(entities=5, n_obs_steps=2, horizon=16, layers=4, image=False)
        ActionflowPolicy(make_config(workload, "cpu", False)).save_pretrained(ckpt)
    missing = [
        k
        for k in steps
        if not all(
            (ckpt / EXPORT_DIR / artefact_name(device, k, 1, guided)).is_dir() for guided in (False, True)
        )
    ]
    export = {}
    if missing:
        t0 = time.perf_counter()
        cmd = [sys.executable, "-m", "lerobot_actionflow.export", str(ckpt), "--device", device, "--steps"]
        subprocess.run([*cmd, *map(str, missing)], check=True)
        export = {"exported_now": missing, "export_s": round(time.perf_counter() - t0, 1)}
    return ckpt, export


def run_variant(variant: str, ckpt: Path, args) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", variant, "--checkpoint", str(ckpt)]
    cmd += ["--device", args.device, "--threads", str(args.threads), "--steps", *map(str, args.steps)]
    cmd += ["--repeats", str(args.repeats), "--warmup", str(args.warmup)]
    spawn = time.time()
    proc = subprocess.run(
        [*cmd, "--spawn-time", repr(spawn)], capture_output=True, text=True, env={**os.environ}
    )
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "failed"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def table(results: dict, steps: list[int]) -> str:
    head = "| variant | import s | first action s | " + " | ".join(f"K={k} median / p90 ms" for k in steps)
    lines = [head + " |", "| --- " * (3 + len(steps)) + "|"]
    for name, r in results.items():
        if "error" in r:
            lines.append(f"| {name} | error: {r['error']} |")
            continue
        for suffix in ("", "_guided"):
            if f"K{steps[0]}{suffix}" not in r:
                continue
            cells = [
                f"{r[f'K{k}{suffix}']['median_ms']:.2f} / {r[f'K{k}{suffix}']['p90_ms']:.2f}" for k in steps
            ]
            firsts = f"{r['import_s']:.2f} | {r['first_action_s']:.2f}" if not suffix else " | "
            lines.append(f"| {name}{suffix.replace('_', ', ')} | {firsts} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/actionflow_bench_inference"))
    ap.add_argument("--variants", nargs="+", default=[*ACTIONFLOW_VARIANTS, *DIFFUSION_VARIANTS])
    ap.add_argument("--steps", type=int, nargs="+", default=[2, 4, 10], help="K / IS values")
    ap.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    ap.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    ap.add_argument("--repeats", type=int, default=100)
    ap.add_argument("--warmup", type=int, default=10)
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--checkpoint", help=argparse.SUPPRESS)
    ap.add_argument("--spawn-time", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(args)))
        return
    ckpt, export = make_checkpoint(args.workdir, args.device, args.steps)
    results = {}
    for variant in args.variants:
        results[variant] = run_variant(variant, ckpt, args)
        print(variant, json.dumps(results[variant]), file=sys.stderr, flush=True)
    report = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "device": args.device,
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "load_average": os.getloadavg(),
        "checkpoint": str(ckpt),
        **export,
        "results": results,
    }
    if "exported" in results and "diffusion_default" in results and 2 in args.steps:
        if "error" not in results["exported"] and "error" not in results["diffusion_default"]:
            ratio = results["diffusion_default"]["K2"]["median_ms"] / results["exported"]["K2"]["median_ms"]
            report["diffusion_default_over_exported_at_2_steps"] = round(ratio, 1)
    if all(v in results and "error" not in results[v] for v in ("eager", "exported")):
        report["guided_eager_over_exported"] = {
            f"K{k}": round(
                results["eager"][f"K{k}_guided"]["median_ms"]
                / results["exported"][f"K{k}_guided"]["median_ms"],
                2,
            )
            for k in args.steps
        }
    print(json.dumps(report, indent=2))
    print(table(results, args.steps))


if __name__ == "__main__":
    main()
