"""Chunk latency of trained checkpoints at batch 1, per number of inference steps (IS).

The latency column of the few-step study (issue #21): for each checkpoint and each IS, the
median wall time of one ``policy.predict_action_chunk`` on a real observation of the task (one
``reset`` of the LeRobot env, through LeRobot's env and policy preprocessors, already on the
device; the policy's observation history filled by one ``select_action``, as at an episode's first
step), with IS network calls set as the sweep sets them
(:func:`lerobot_actionflow.evaluation.sweep.set_inference_steps`, so a midpoint checkpoint makes
``IS / 2`` steps). Checkpoints and IS are timed round-robin, one call of each in turn, so that
all see the same machine load; the ratios between cells are the robust figure on a shared
machine. The observation has poses, state and the task's cameras, no point cloud: a checkpoint
that reads a cloud is not timed by this script.

``--guided NAME ...`` also times those flow checkpoints as ``guide_to_previous_chunk`` samples
every chunk after the first (cells ``<name>+guided/IS<n>``): guided toward the unexecuted tail
of a chunk of the same observation, with no delay (:class:`GuidedChunks`).

Every checkpoint samples eagerly, except those named by ``--exported NAME ...``: their
``actionflow-export`` artefacts (plain and guided) serve the chunks that have one. One directory
may be given under two names, to time it both ways side by side:

    python benchmarks/bench_checkpoint_latency.py --task StackThree_D0 --inference-steps 2 4 \
        --checkpoints eager=$CKPT exported=$CKPT --exported exported --guided eager exported

    python benchmarks/bench_checkpoint_latency.py --task Lift --inference-steps 1 2 4 10 \\
        --checkpoints default=/work/study/Lift/.../pretrained_model shortcut=/.../pretrained_model \\
            solver_midpoint=/work/study/Lift/.../pretrained_model --midpoint solver_midpoint \\
        --json benchmarks/results/few_step_latency_Lift.json
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

from lerobot_actionflow.registry import register_all
from lerobot_actionflow.schema import ACTION_KEY


def load(checkpoint: str, task: str):
    """The policy (eval mode, CPU) and one preprocessed observation of ``task`` at batch 1."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.factory import make_env, make_env_pre_post_processors
    from lerobot.envs.utils import close_envs, preprocess_observation
    from lerobot.policies.factory import make_policy, make_pre_post_processors

    from lerobot_actionflow.envs.configuration import ActionFlowEnvConfig

    env_cfg = ActionFlowEnvConfig(task=task)
    policy_cfg = PreTrainedConfig.from_pretrained(checkpoint)
    policy_cfg.pretrained_path = Path(checkpoint)
    policy_cfg.device = "cpu"
    policy = make_policy(cfg=policy_cfg, env_cfg=env_cfg).eval()
    preprocessor, _ = make_pre_post_processors(
        policy_cfg=policy_cfg,
        pretrained_path=checkpoint,
        preprocessor_overrides={"device_processor": {"device": "cpu"}},
    )
    env_pre, _ = make_env_pre_post_processors(env_cfg=env_cfg, policy_cfg=policy_cfg)
    envs = make_env(env_cfg, n_envs=1, use_async_envs=False)
    try:
        (vec_env,) = [v for tasks in envs.values() for v in tasks.values()]
        obs, _ = vec_env.reset(seed=1000)
        batch = preprocessor(env_pre(preprocess_observation(obs)))
    finally:
        close_envs(envs)
    return policy, fill_history(policy, batch)


def fill_history(policy, batch: dict) -> dict:
    """``reset``, then one ``select_action`` on ``batch``, as at an episode's first step: this fills
    the policy's observation history, from which LeRobot's diffusion predicts. Returns ``batch``
    with every key the policy keeps a history of (diffusion's ``observation.images``, its stacked
    cameras, too), so that ``predict_action_chunk(batch)`` reads all of them."""
    policy.reset()
    with torch.inference_mode():
        policy.select_action(batch)
    history = getattr(policy, "_queues", None) or {}
    return {**batch, **{k: q[-1] for k, q in history.items() if k not in batch and k != ACTION_KEY and q}}


class GuidedChunks:
    """A flow policy whose chunks are all guided toward one leftover, as
    ``guide_to_previous_chunk`` guides every chunk after an episode's first at no delay:
    ``predict_action_chunk(batch, inference_delay=0, prev_chunk_left_over=leftover)``, where
    ``leftover`` is the tail past ``n_action_steps`` of a plain chunk of ``batch``."""

    def __init__(self, policy, batch: dict):
        if not (hasattr(policy, "supports_rtc") and policy.supports_rtc()):
            raise ValueError(f"policy type {policy.config.type!r} has no guided sampler (supports_rtc)")
        if getattr(policy.config, "solver", "euler") != "euler":
            raise ValueError(
                f"the guidance steers Euler steps, the checkpoint's solver is {policy.config.solver!r}"
            )
        self.policy, self.config = policy, policy.config
        with torch.inference_mode():
            self.leftover = policy.predict_action_chunk(batch)[:, policy.config.n_action_steps :]

    def predict_action_chunk(self, batch: dict):
        return self.policy.predict_action_chunk(batch, inference_delay=0, prev_chunk_left_over=self.leftover)


def choose_samplers(policies: dict, exported: list[str]) -> dict[str, list[str]]:
    """Drop every policy's exported samplers but those of the ``exported`` names (so that the
    others sample eagerly); returns name -> the artefacts in use. Raises ValueError for an
    ``exported`` name with no accepted artefact."""
    in_use = {}
    for name, (policy, _) in policies.items():
        samplers = getattr(policy, "exported_samplers", None)
        if name not in exported:
            if samplers is not None:
                policy.exported_samplers = None
            continue
        if samplers is None or not samplers.keys():
            raise ValueError(
                f"--exported {name}: the checkpoint has no exported sampler this policy accepts "
                "(run actionflow-export on it; refusals are logged above)"
            )
        in_use[name] = [key.describe() for key in samplers.keys()]
    return in_use


def time_cells(
    policies: dict, steps: list[int], warmup: int, repeats: int, solvers: dict[str, str] | None = None
) -> tuple[dict[str, dict], dict[str, str]]:
    """``"<name>/IS<n>"`` -> median and p90 ms of ``predict_action_chunk``, timed round-robin, and
    ``"<name>/IS<n>"`` -> why a cell is not a cell of that policy (e.g. an odd IS with midpoint
    steps); a policy with no cell at all is an error (ValueError), raised before any timing.
    ``solvers``: name -> ODE solver replacing a flow checkpoint's (LeRobot's ``diffusion`` has
    none: its IS sets DDIM, or DDPM at its trained steps)."""
    from lerobot_actionflow.evaluation.sweep import set_inference_steps

    solvers = {
        name: (solvers or {}).get(name, getattr(p.config, "solver", None))
        for name, (p, _) in policies.items()
    }
    cells, skipped = [], {}
    for name, (policy, _) in policies.items():
        for n in steps:
            try:
                set_inference_steps(policy, n, solver=solvers[name])
            except ValueError as e:
                skipped[f"{name}/IS{n}"] = str(e)
                continue
            cells.append((name, n))
    untimed = [name for name in policies if all(cell_name != name for cell_name, _ in cells)]
    if untimed:
        raise ValueError(f"no IS of {steps} can be set for {untimed}: {skipped}")
    times: dict[tuple[str, int], list[float]] = {c: [] for c in cells}
    with torch.inference_mode():
        for i in range(warmup + repeats):
            for name, n in cells:
                policy, batch = policies[name]
                set_inference_steps(policy, n, solver=solvers[name])
                t0 = time.perf_counter()
                policy.predict_action_chunk(batch)
                if i >= warmup:
                    times[(name, n)].append((time.perf_counter() - t0) * 1e3)
    out = {}
    for (name, n), ts in times.items():
        ts.sort()
        out[f"{name}/IS{n}"] = {
            "median_ms": round(statistics.median(ts), 3),
            "p90_ms": round(statistics.quantiles(ts, n=10, method="inclusive")[-1], 3)
            if len(ts) > 1
            else ts[0],
        }
    return out, skipped


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", required=True, help="env task of the observation, e.g. Lift")
    ap.add_argument(
        "--checkpoints", nargs="+", required=True, help="NAME=…/pretrained_model, one per candidate"
    )
    ap.add_argument(
        "--midpoint", nargs="*", default=[], help="names sampled with midpoint steps (IS = 2 x steps)"
    )
    ap.add_argument(
        "--guided", nargs="*", default=[], help="names also timed with guidance toward a previous chunk"
    )
    ap.add_argument(
        "--exported", nargs="*", default=[], help="names whose exported samplers serve their chunks"
    )
    ap.add_argument("--inference-steps", type=int, nargs="+", default=[1, 2, 4, 10])
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    ap.add_argument("--json", type=Path, default=None, help="also write the report here")
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.warmup < 0 or min(args.inference_steps) < 1:
        raise SystemExit(
            f"need --repeats >= 1, --warmup >= 0 and --inference-steps >= 1, got {args.repeats}, "
            f"{args.warmup}, {args.inference_steps}"
        )
    named = {}
    for item in args.checkpoints:
        name, sep, path = item.partition("=")
        if not sep or not name or not Path(path).is_dir():
            raise SystemExit(f"--checkpoints {item!r}: expected NAME=<existing pretrained_model directory>")
        if name in named:
            raise SystemExit(f"--checkpoints: the name {name!r} is given twice")
        named[name] = str(Path(path).resolve())  # as latency_sweep.py --real_latency matches them
    for flag, names in (
        ("--midpoint", args.midpoint),
        ("--guided", args.guided),
        ("--exported", args.exported),
    ):
        if set(names) - set(named):
            raise SystemExit(f"{flag} {sorted(set(names) - set(named))}: not among the --checkpoints names")
    if set(args.midpoint) & set(args.guided):
        raise SystemExit(
            f"--guided {sorted(set(args.midpoint) & set(args.guided))}: the guidance steers Euler steps, "
            "not midpoint ones"
        )
    torch.set_num_threads(args.threads)
    register_all()
    policies = {name: load(path, args.task) for name, path in named.items()}
    try:
        exported = choose_samplers(policies, args.exported)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    for name in args.guided:
        try:
            policies[f"{name}+guided"] = (GuidedChunks(*policies[name]), policies[name][1])
        except ValueError as e:
            raise SystemExit(f"--guided {name}: {e}") from None
    report = {
        "date": time.strftime("%Y-%m-%d"),
        "torch": torch.__version__,
        "cpu": platform.processor() or platform.machine(),
        "cpu_threads": torch.get_num_threads(),
        "task": args.task,
        "checkpoints": named,
        "repeats": args.repeats,
        "warmup": args.warmup,
        "midpoint": args.midpoint,
        "guided": args.guided,
        "exported": exported,
    }
    try:
        timed, skipped = time_cells(
            policies, args.inference_steps, args.warmup, args.repeats, {n: "midpoint" for n in args.midpoint}
        )
    except ValueError as e:
        raise SystemExit(str(e)) from None
    report["latency_batch1"], report["skipped"] = timed, skipped
    for cell, why in skipped.items():
        print(f"skipped {cell}: {why}", file=sys.stderr)
    text = json.dumps(report, indent=2)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text + "\n")
    print(text)
    return report


if __name__ == "__main__":
    main()
