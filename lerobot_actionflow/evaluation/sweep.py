"""Success rate per number of inference steps (IS), for trained checkpoints (paper, App. E).

For each checkpoint and each IS, the policy is rolled out in a LeRobot env with LeRobot's own
evaluation machinery (``make_env``, ``make_policy``, ``make_pre_post_processors``,
``eval_policy`` from ``lerobot_eval``); only the number of network calls per chunk changes:

- ``actionflow`` and ``euclidean_flow``: ``K = IS`` Euler steps (on SE(3) x R for actionflow, in
  R^n for euclidean_flow; grid spacing from the checkpoint, or ``--time_spacing``), or
  ``K = IS / 2`` midpoint steps when the checkpoint's config has ``solver="midpoint"`` or
  ``--solver=midpoint`` asks for it (even IS only; the solver is a sampling choice, no retraining);
- ``diffusion`` (LeRobot's Diffusion Policy): DDIM with IS steps for ``IS < num_train_timesteps``,
  DDPM when ``IS == num_train_timesteps`` (the paper's protocol; 100 by default).

Every IS uses the same env seeds (``--seed`` onwards) and starts the policy's noise from torch
seed ``--seed``, so the rates are paired comparisons, and a checkpoint evaluated again on the same
machine and thread count gives the same rates.

Usage::

    python -m lerobot_actionflow.evaluation.sweep \\
        --checkpoints='[outputs/train/ef/checkpoints/last/pretrained_model]' \\
        --env.type=<env type> --env.task=<task> \\
        --inference_steps='[2,5,10,20,100]' --eval.n_episodes=50 --eval.batch_size=10 \\
        --output_dir=outputs/sweep

Prints a table and writes ``<output_dir>/sweep_results.json``.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import draccus
import numpy as np
from lerobot.configs.default import EvalConfig
from lerobot.envs.configs import EnvConfig

from lerobot_actionflow.evaluation.provenance import DIGEST_KEY, weights_digest
from lerobot_actionflow.flow.schedules import SOLVERS, network_calls
from lerobot_actionflow.policies.execution import guides_chunks


@dataclass
class SweepConfig:
    """Command-line configuration of the sweep (parsed with draccus, like LeRobot's CLIs)."""

    env: EnvConfig
    # Checkpoint directories (…/checkpoints/<step>/pretrained_model) of actionflow, euclidean_flow
    # or diffusion.
    checkpoints: list[str] = field(default_factory=list)
    inference_steps: list[int] = field(default_factory=lambda: [2, 5, 10, 20, 100])
    # actionflow / euclidean_flow only: "uniform" or "exponential"; None keeps each checkpoint's setting.
    time_spacing: str | None = None
    # actionflow / euclidean_flow only: "euler" or "midpoint"; None keeps each checkpoint's setting.
    solver: str | None = None
    # actionflow / euclidean_flow only: select_action's guidance toward the previous chunk
    # (`guide_to_previous_chunk`); None keeps each checkpoint's setting (default: on with Euler).
    guide_to_previous_chunk: bool | None = None
    eval: EvalConfig = field(default_factory=lambda: EvalConfig(n_episodes=50, batch_size=10))
    seed: int = 1000
    # None: the checkpoint's device if available, else what LeRobot picks.
    device: str | None = None
    output_dir: Path | None = None


def set_inference_steps(
    policy, num_steps: int, time_spacing: str | None = None, solver: str | None = None
) -> str:
    """Make ``policy`` spend ``num_steps`` network calls per chunk; returns the sampler's name.

    ``actionflow`` / ``euclidean_flow``: ``K = num_steps`` steps with ``solver="euler"``; with
    ``solver="midpoint"`` (two calls per step) ``K = num_steps / 2``, and an odd ``num_steps`` is
    refused. ``time_spacing`` and ``solver`` replace the checkpoint's when given. The name is
    ``<solver>-<time spacing>``, with ``-guided`` when ``select_action`` guides each chunk toward
    the previous one (:func:`~lerobot_actionflow.policies.execution.guides_chunks`).
    ``diffusion``: DDIM with ``num_steps`` steps, or DDPM when
    ``num_steps`` equals the trained ``num_train_timesteps`` (built from the trained noise schedule
    with ``from_config``, so betas and clipping are unchanged).
    """
    if not isinstance(num_steps, int) or num_steps < 1:
        raise ValueError(f"the number of inference steps must be an integer >= 1, got {num_steps!r}")
    kind = policy.config.type
    if kind in ("euclidean_flow", "actionflow"):
        if solver is not None:
            if solver not in SOLVERS:
                raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
            policy.config.solver = solver
        solver = getattr(policy.config, "solver", "euler")
        calls_per_step = network_calls(1, solver)
        if num_steps % calls_per_step:
            raise ValueError(
                f"{num_steps} inference steps (network calls) with solver={solver!r}, which calls the "
                f"network {calls_per_step} times per integration step: use a multiple of {calls_per_step}"
            )
        policy.config.num_inference_steps = num_steps // calls_per_step
        if time_spacing is not None:
            policy.config.time_spacing = time_spacing
        guided = "-guided" if guides_chunks(policy.config) else ""
        return f"{solver}-{policy.config.time_spacing}{guided}"
    if kind == "diffusion":
        from diffusers import DDIMScheduler, DDPMScheduler

        if time_spacing is not None or solver is not None:
            raise ValueError("time_spacing and solver apply to the flow policies only, not to diffusion")
        model = policy.diffusion
        trained = model.noise_scheduler.config.num_train_timesteps
        if num_steps > trained:
            raise ValueError(f"diffusion was trained with {trained} steps: cannot sample with {num_steps}")
        cls = DDPMScheduler if num_steps == trained else DDIMScheduler
        if type(model.noise_scheduler) is not cls:
            model.noise_scheduler = cls.from_config(model.noise_scheduler.config)
        model.num_inference_steps = num_steps
        return "ddpm" if cls is DDPMScheduler else "ddim"
    raise ValueError(
        f"inference-step sweep supports 'actionflow', 'euclidean_flow' and 'diffusion', got '{kind}'"
    )


def _evaluate_checkpoint(cfg: SweepConfig, checkpoint: str) -> list[dict]:
    """One row per IS: success rate over ``cfg.eval.n_episodes`` per task, all tasks pooled."""
    import torch
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.factory import make_env, make_env_pre_post_processors
    from lerobot.envs.utils import close_envs
    from lerobot.policies.factory import make_policy, make_pre_post_processors
    from lerobot.scripts.lerobot_eval import eval_policy

    policy_cfg = PreTrainedConfig.from_pretrained(checkpoint)
    policy_cfg.pretrained_path = Path(checkpoint)
    if cfg.device is not None:
        policy_cfg.device = cfg.device
    policy = make_policy(cfg=policy_cfg, env_cfg=cfg.env)
    policy.eval()
    if cfg.guide_to_previous_chunk is not None:
        if not hasattr(policy.config, "guide_to_previous_chunk"):
            if cfg.guide_to_previous_chunk:
                raise ValueError(f"policy type {policy_cfg.type!r} has no guidance toward the previous chunk")
        else:
            policy.config.guide_to_previous_chunk = cfg.guide_to_previous_chunk
    device = str(policy.config.device)
    preprocessor, postprocessor = make_pre_post_processors(
        policy_cfg=policy_cfg,
        pretrained_path=checkpoint,
        preprocessor_overrides={"device_processor": {"device": device}},
    )
    env_pre, env_post = make_env_pre_post_processors(env_cfg=cfg.env, policy_cfg=policy_cfg)
    envs = make_env(cfg.env, n_envs=cfg.eval.batch_size, use_async_envs=cfg.eval.use_async_envs)
    digest = weights_digest(checkpoint)
    rows = []
    try:
        for num_steps in cfg.inference_steps:
            sampler = set_inference_steps(policy, num_steps, cfg.time_spacing, cfg.solver)
            successes: list[bool] = []
            start = time.perf_counter()
            for tasks in envs.values():
                for vec_env in tasks.values():
                    torch.manual_seed(cfg.seed)  # the same policy noise draws at every IS
                    with torch.no_grad():
                        info = eval_policy(
                            vec_env,
                            policy,
                            env_pre,
                            env_post,
                            preprocessor,
                            postprocessor,
                            n_episodes=cfg.eval.n_episodes,
                            start_seed=cfg.seed,
                        )
                    successes += [bool(ep["success"]) for ep in info["per_episode"]]
            rows.append(
                {
                    "checkpoint": checkpoint,
                    "policy": policy_cfg.type,
                    "inference_steps": num_steps,
                    "sampler": sampler,
                    "n_episodes": len(successes),
                    "pc_success": 100.0 * float(np.mean(successes)) if successes else float("nan"),
                    "eval_s": time.perf_counter() - start,
                    DIGEST_KEY: digest,
                }
            )
            logging.info("sweep %s", rows[-1])
    finally:
        close_envs(envs)
    return rows


def format_table(rows: list[dict]) -> str:
    """Markdown table of the sweep rows."""
    lines = [
        "| checkpoint | policy | IS | sampler | success % | episodes | eval s |",
        "| --- | --- | ---: | --- | ---: | ---: | ---: |",
    ]
    for r in rows:
        lines.append(
            f"| {r['checkpoint']} | {r['policy']} | {r['inference_steps']} | {r['sampler']} | "
            f"{r['pc_success']:.1f} | {r['n_episodes']} | {r['eval_s']:.1f} |"
        )
    return "\n".join(lines)


def run_sweep(cfg: SweepConfig) -> list[dict]:
    """Evaluate every checkpoint at every IS; writes ``sweep_results.json`` if ``output_dir``."""
    if not cfg.checkpoints:
        raise ValueError("no checkpoints given: pass --checkpoints='[path/to/pretrained_model, ...]'")
    rows = [row for ckpt in cfg.checkpoints for row in _evaluate_checkpoint(cfg, ckpt)]
    if cfg.output_dir is not None:
        Path(cfg.output_dir).mkdir(parents=True, exist_ok=True)
        (Path(cfg.output_dir) / "sweep_results.json").write_text(json.dumps(rows, indent=2))
    return rows


def main(argv: list[str] | None = None) -> list[dict]:
    """CLI entry point (``python -m lerobot_actionflow.evaluation.sweep --help``)."""
    from lerobot.utils.import_utils import register_third_party_plugins

    logging.basicConfig(level=logging.INFO)
    register_third_party_plugins()  # our policy and env types, like lerobot-eval
    cfg = draccus.parse(SweepConfig, args=sys.argv[1:] if argv is None else argv)
    rows = run_sweep(cfg)
    print(format_table(rows))
    return rows


if __name__ == "__main__":
    main()
