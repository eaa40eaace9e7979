"""``actionflow-export``: compile a trained checkpoint's sampler ahead of time (``actionflow`` or
``euclidean_flow``).

    actionflow-export CHECKPOINT [--steps 2 4] [--batch-sizes 1] [--device cpu|cuda] [--no-guided]

``CHECKPOINT`` is a ``pretrained_model`` directory, or a directory holding one (a checkpoint step
directory, or a training output whose ``checkpoints/last/pretrained_model`` is used). For each K
and batch size (1 for a robot; the number of envs for ``lerobot-eval``) the sampler is exported
with ``torch.export`` and compiled by AOTInductor (minutes each on a 2-core CPU), then written to
``pretrained_model/exported_sampler/<device>_k<K>_b<B>/`` (see
:mod:`lerobot_actionflow.policies.exported`); with the Euler solver, the guided sampler
too (``..._guided/``: the chunks after an episode's first with ``guide_to_previous_chunk``, the
default, and ``lerobot-rollout --inference.type=rtc``), unless ``--no-guided``.
``from_pretrained``, and so ``lerobot-eval`` and any deployment loop, then samples with them from
the first chunk. Each artefact is checked before the command ends: reloaded from disk, it must
give the eager sampler's actions on the same observations and noise (and, guided, the same
leftover chunk and delay).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

#: Largest difference allowed between exported and eager actions on the same noise.
EXPORT_TOLERANCE = 1e-5
#: The inference delay (control steps) of the guided check: some actions frozen, some guided.
CHECK_DELAY = 2


def resolve_pretrained_dir(path: str | Path) -> Path:
    """The ``pretrained_model`` directory that ``path`` names or holds.

    Raises:
        FileNotFoundError: naming the path and the places looked at.
    """
    path = Path(path)
    candidates = [path, path / "pretrained_model", path / "checkpoints" / "last" / "pretrained_model"]
    for candidate in candidates:
        if (candidate / "config.json").is_file() and (candidate / "model.safetensors").is_file():
            return candidate
    looked = ", ".join(str(c) for c in candidates)
    raise FileNotFoundError(
        f"no checkpoint at {path}: none of {looked} holds a config.json and a model.safetensors"
    )


def policy_class(policy_type: str):
    """The policy class of an exportable policy type, or None."""
    if policy_type == "actionflow":
        from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy

        return ActionflowPolicy
    if policy_type == "euclidean_flow":
        from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy

        return EuclideanFlowPolicy
    return None


def load_policy(pretrained_dir: Path, device: str):
    """The policy of a checkpoint on ``device``, without its exported samplers.

    Raises:
        ValueError: the checkpoint is of a policy type that has no exportable sampler.
    """
    from lerobot.configs.policies import PreTrainedConfig

    from lerobot_actionflow.registry import register_all

    register_all()
    config = PreTrainedConfig.from_pretrained(pretrained_dir)
    cls = policy_class(config.type)
    if cls is None:
        raise ValueError(
            f"{pretrained_dir} holds a '{config.type}' policy; actionflow-export exports 'actionflow' "
            "and 'euclidean_flow'"
        )
    config.device = device
    policy = cls.from_pretrained(pretrained_dir, config=config)
    policy.exported_samplers = None
    return policy


def random_observations(policy, batch_size: int, generator, device: str) -> dict:
    """A history ``(B, n_obs_steps, ...)`` of every input feature of the policy's config: poses
    with random rotations and positions, the rest uniform in ``[0, 1)``."""
    import torch

    from lerobot_actionflow.geometry import random_rotation
    from lerobot_actionflow.geometry.se3 import rp_to_pose7
    from lerobot_actionflow.schema import POSES_KEY

    b, s = batch_size, policy.config.n_obs_steps
    batch = {}
    for key, feature in policy.config.input_features.items():
        if key == POSES_KEY:
            n = feature.shape[0]
            r = random_rotation(b, s, n, generator=generator)
            batch[key] = rp_to_pose7(r, 0.3 * torch.randn(b, s, n, 3, generator=generator))
        else:
            batch[key] = torch.rand(b, s, *feature.shape, generator=generator)
    return {k: v.to(device) for k, v in batch.items()}


def random_noise(policy, batch_size: int, generator, device: str):
    """The initial noise of one chunk in the form the policy's ``predict_action_chunk`` takes."""
    import torch

    cfg = policy.config
    if policy.name == "actionflow":
        from lerobot_actionflow.flow import se3 as se3_flow

        noise = se3_flow.draw_local_noise(
            batch_size, cfg.horizon, cfg.noise_sigma, cfg.noise_rotation, cfg.noise_kappa, generator=generator
        )
        return se3_flow.LocalNoise(noise.r.to(device), noise.p.to(device), noise.g.to(device))
    return torch.randn(batch_size, cfg.horizon, cfg.action_feature.shape[0], generator=generator).to(device)


def check_against_eager(
    pretrained_dir: Path, device: str, steps: list[int], batch_sizes: list[int], guided: bool = False
) -> dict[tuple[int, int, bool], float]:
    """Reload the checkpoint with its artefacts; for each K, batch size and program (plain, and
    guided with ``guided``), the largest difference between the exported and the eager actions on
    random observations and noise. The guided program is checked through ``predict_action_chunk``
    with a leftover chunk (an eager chunk's actions from ``n_action_steps`` on) and
    :data:`CHECK_DELAY`.

    Raises:
        RuntimeError: an artefact was refused, or differs from eager by more than
            :data:`EXPORT_TOLERANCE`.
    """
    import torch

    from lerobot_actionflow.policies.exported import ArtefactKey

    policy = load_policy(pretrained_dir, device)
    policy.attach_exported_samplers(pretrained_dir)
    cfg = policy.config
    gen = torch.Generator().manual_seed(0)
    errors = {}
    for b in batch_sizes:
        batch = random_observations(policy, b, gen, device)
        noise = random_noise(policy, b, gen, device)
        samplers = policy.exported_samplers
        for k in steps:
            policy.exported_samplers = None
            first = policy.predict_action_chunk(batch, noise=noise, num_inference_steps=k)
            leftover = first[:, cfg.n_action_steps :]
            for program in (False, True) if guided else (False,):
                key = ArtefactKey(device, k, b, program)
                if samplers is None or samplers.get(torch.device(device), k, b, program) is None:
                    raise RuntimeError(f"the artefact for {key.describe()} was refused after export")
                kw = {"noise": noise, "num_inference_steps": k}
                if program:
                    kw |= {"inference_delay": CHECK_DELAY, "prev_chunk_left_over": leftover}
                actions = []
                for samplers_in_use in (samplers, None):
                    policy.exported_samplers = samplers_in_use
                    actions.append(policy.predict_action_chunk(batch, **kw))
                errors[k, b, program] = float((actions[0] - actions[1]).abs().max())
                if not errors[k, b, program] <= EXPORT_TOLERANCE:
                    raise RuntimeError(
                        f"the exported sampler for {key.describe()} differs from eager by "
                        f"{errors[k, b, program]:.2e} (more than {EXPORT_TOLERANCE:.0e})"
                    )
        policy.exported_samplers = samplers
    return errors


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", help="pretrained_model directory (or a directory holding one)")
    ap.add_argument("--steps", type=int, nargs="+", default=None, help="K values (default: the config's)")
    ap.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    ap.add_argument(
        "--batch-sizes",
        type=int,
        nargs="+",
        default=[1],
        help="batch sizes (1: a robot; lerobot-eval: n_envs)",
    )
    ap.add_argument(
        "--guided",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="also export the guided sampler (default: when the policy's solver is Euler)",
    )
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    from lerobot_actionflow.policies.exported import ArtefactKey, export_sampler

    try:
        pretrained_dir = resolve_pretrained_dir(args.checkpoint)
        policy = load_policy(pretrained_dir, args.device)
    except (FileNotFoundError, ValueError) as e:
        print(f"actionflow-export: {e}", file=sys.stderr)
        return 2
    steps = args.steps or [policy.config.num_inference_steps]
    for name, values in (("--steps", steps), ("--batch-sizes", args.batch_sizes)):
        if any(v < 1 for v in values):
            print(f"actionflow-export: {name} must be >= 1, got {values}", file=sys.stderr)
            return 2
    euler = policy.config.solver == "euler"
    guided = euler if args.guided is None else args.guided
    if guided and not euler:
        print(
            f"actionflow-export: --guided needs the Euler solver; the policy's is {policy.config.solver!r}",
            file=sys.stderr,
        )
        return 2
    for k in steps:
        for b in args.batch_sizes:
            for program in (False, True) if guided else (False,):
                t0 = time.perf_counter()
                out = export_sampler(policy, pretrained_dir, k, args.device, b, guided=program)
                size = (out / "sampler.pt2").stat().st_size / 2**20
                key = ArtefactKey(args.device, k, b, program)
                print(f"{key.describe()}: {out} ({size:.1f} MiB, {time.perf_counter() - t0:.0f} s)")
    checks = check_against_eager(pretrained_dir, args.device, steps, args.batch_sizes, guided)
    for (k, b, program), err in checks.items():
        what = "the same noise, leftover and delay" if program else "the same noise"
        key = ArtefactKey(args.device, k, b, program)
        print(f"{key.describe()}: exported == eager on {what} (max |difference| {err:.1e})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
