"""Ahead-of-time exported samplers of the flow policies (``actionflow``, ``euclidean_flow``),
stored with a checkpoint.

An *artefact* is a policy's whole K-step sampler exported with ``torch.export`` and compiled by
AOTInductor into a shared library, with the weights frozen in as constants. Loading one is a
``dlopen``: no Python tracing, no compile wait, no guards, one C++ call per chunk. Each policy
names its program class (``sampler_program``: the module that gets exported, its inputs and
their example values); there are two programs per policy:

* plain: checked observations and initial noise in, the normalised ``(B, H, A)`` action chunk
  out. It serves an episode's first chunk, and every chunk when the guidance is off.
* guided: the same inputs, then the known actions ``(B, H, A)``, their guidance weights
  ``(B, H)`` and the frozen mask ``(B, H)`` (real-time chunking: ``guide_to_previous_chunk``, the
  default, and ``lerobot-rollout --inference.type=rtc``). The delay and the weights are inputs,
  so one artefact serves every delay.

Layout, inside a checkpoint's ``pretrained_model/`` directory::

    exported_sampler/<device>_k<K>_b<B>[_guided]/sampler.pt2     the AOTInductor package
    exported_sampler/<device>_k<K>_b<B>[_guided]/manifest.json   what it was built from

An artefact is used only when its manifest matches the policy that loads it: the same format,
policy type and torch version, the program's inputs, the SHA-256 of the weights (every tensor
of the state dict, in name order, with its dtype and shape) and of the configuration (every
field except those listed in :data:`SAMPLER_INDEPENDENT_FIELDS`), and the SHA-256 of
``sampler.pt2`` itself. Anything else is refused with a log line naming the difference, and
that K samples eagerly. After loading, the parameters' version counters are watched: an
in-place change (an optimiser step, ``load_state_dict``) makes the next chunk re-hash the
weights, and artefacts whose weights no longer match are dropped with a log line. Writes
through ``.data`` bypass the version counters; call :meth:`ExportedSamplers.verify` after such
an edit.

Each artefact serves one program, device type, K and batch size B (static shapes: inductor's
autotuned GEMMs are specialised to them; 1 for a robot, the number of envs for ``lerobot-eval``).
A chunk with no artefact for its program, device, K and batch size samples eagerly, logged once.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, fields
from functools import partial
from pathlib import Path
from typing import NamedTuple

import draccus
import torch
from huggingface_hub import snapshot_download
from huggingface_hub.errors import HfHubHTTPError
from torch import Tensor, nn

from lerobot_actionflow.policies.execution import RealTimeExecutionConfig
from lerobot_actionflow.policies.flow_options import check_rtc_solver

logger = logging.getLogger(__name__)

#: The artefacts' directory inside a ``pretrained_model/`` directory.
EXPORT_DIR = "exported_sampler"
PACKAGE_FILE = "sampler.pt2"
MANIFEST_FILE = "manifest.json"
#: Bumped whenever the artefact's calling convention or manifest changes.
FORMAT_VERSION = 2
#: Configuration fields (of either policy; a name a config lacks is ignored) that do not change
#: what the sampler computes for a given K: they act before or after it, only in training, or
#: only through the weights (the execution options decide which chunk is guided and how,
#: through the guided program's inputs). Every other field is part of the fingerprint, so a
#: field added later can only cause a refusal, never a stale artefact.
SAMPLER_INDEPENDENT_FIELDS = frozenset(
    {f.name for f in fields(RealTimeExecutionConfig)}
    | {
        "device",
        "use_amp",
        "use_peft",
        "push_to_hub",
        "repo_id",
        "private",
        "tags",
        "license",
        "pretrained_path",
        "n_action_steps",
        "num_inference_steps",
        "rotation_tolerance",
        "compile_sampler",
        "compile_mode",
        "dropout",
        "train_time_distribution",
        "train_time_beta",
        "train_time_logit_normal",
        "shortcut_fraction",
        "loss_weight_translation",
        "loss_weight_rotation",
        "loss_weight_gripper",
        "optimizer_lr",
        "optimizer_betas",
        "optimizer_eps",
        "optimizer_weight_decay",
        "optimizer_grad_clip_norm",
        "scheduler_warmup_steps",
        "scheduler_name",
        "drop_n_last_frames",
        "do_mask_loss_for_padding",
        "p_drop_emb",
        "p_drop_attn",
        "gradient_checkpointing",
        "pretrained_backbone_weights",
    }
)


#: AOTInductor options per device type. Both freeze the weights (constants inductor can fold and
#: pre-pack). On the CPU, ``max_autotune`` with the C++ GEMM template times inductor's own
#: micro-kernel GEMMs against ATen's for each matmul and keeps the faster: at ActionFlow's
#: batch-1 sizes (16-26 tokens) they are 2-7x faster than oneDNN's (benchmarks/RESULTS.md).
INDUCTOR_CONFIGS = {
    "cpu": {"freezing": True, "max_autotune": True, "max_autotune_gemm_backends": "CPP,ATEN"},
    "cuda": {"freezing": True},
}
#: Changes for the guided program. On the CPU, torch 2.11's C++ batched-GEMM template fails to
#: generate code for one of the guided graph's batched products with the pointwise epilogue fused
#: into it (an ``AssertionError`` in ``ir.py``'s indexer, from ``cpp_bmm_template``), so the
#: guided program is built without epilogue fusion.
GUIDED_INDUCTOR_CHANGES = {"cpu": {"epilogue_fusion": False}, "cuda": {}}


def inductor_config(device: str, guided: bool) -> dict:
    """The AOTInductor options of an artefact for ``device`` (the guided program's, with ``guided``)."""
    return {**INDUCTOR_CONFIGS[device], **(GUIDED_INDUCTOR_CHANGES[device] if guided else {})}


class ArtefactKey(NamedTuple):
    """What one artefact serves."""

    device: str
    num_inference_steps: int
    batch_size: int
    guided: bool = False

    def describe(self) -> str:
        """E.g. ``K=2 batch 1 on cpu``, ``guided K=2 batch 1 on cpu``."""
        guided = "guided " if self.guided else ""
        return f"{guided}K={self.num_inference_steps} batch {self.batch_size} on {self.device}"


def artefact_name(device: str, num_inference_steps: int, batch_size: int, guided: bool = False) -> str:
    """Directory name of the artefact for a device type, K, batch size and program, e.g.
    ``cpu_k4_b1`` or ``cpu_k2_b1_guided``."""
    return f"{device}_k{num_inference_steps}_b{batch_size}" + ("_guided" if guided else "")


def weights_fingerprint(module: nn.Module) -> str:
    """SHA-256 of every tensor of ``module.state_dict()``: name, dtype, shape and bytes."""
    digest = hashlib.sha256()
    for name, tensor in sorted(module.state_dict().items()):
        t = tensor.detach().cpu().contiguous()
        digest.update(f"{name}|{t.dtype}|{tuple(t.shape)}|".encode())
        digest.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


def config_fingerprint(config) -> str:
    """SHA-256 of the configuration's JSON encoding, without :data:`SAMPLER_INDEPENDENT_FIELDS`."""
    encoded = draccus.encode(config)
    kept = {k: v for k, v in encoded.items() if k not in SAMPLER_INDEPENDENT_FIELDS}
    return hashlib.sha256(json.dumps(kept, sort_keys=True, default=str).encode()).hexdigest()


def file_fingerprint(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@dataclass(frozen=True)
class Manifest:
    """What an artefact was built from (``manifest.json``).

    Attributes:
        inputs: the tensors the package takes, in order (the program's ``input_names``).
        batch_size: the batch size the package takes.
        guided: the guided program (module docstring).
    """

    format: int
    policy: str
    device: str
    num_inference_steps: int
    torch: str
    dtype: str
    weights_sha256: str
    config_sha256: str
    package_sha256: str
    inputs: tuple[str, ...]
    batch_size: int
    guided: bool = False

    @property
    def key(self) -> ArtefactKey:
        return ArtefactKey(self.device, self.num_inference_steps, self.batch_size, self.guided)

    @classmethod
    def read(cls, path: Path) -> Manifest:
        """Raises ``ValueError`` naming the file when it is not a manifest."""
        try:
            data = json.loads(path.read_text())
            data["inputs"] = tuple(data["inputs"])
            return cls(**data)
        except (OSError, ValueError, TypeError, KeyError) as e:
            raise ValueError(f"{path} is not a readable exported-sampler manifest: {e}") from e

    def write(self, path: Path) -> None:
        path.write_text(json.dumps(asdict(self), indent=2) + "\n")

    def differences(self, expected: Manifest) -> list[str]:
        """The fields that differ from ``expected`` (the package hash excepted), as readable text."""
        names = {
            "weights_sha256": "weights",
            "config_sha256": "configuration",
            "torch": "torch version",
            "num_inference_steps": "K",
        }
        out = []
        for field, mine in asdict(self).items():
            if field in ("package_sha256", "batch_size"):
                continue
            theirs = getattr(expected, field)
            if mine != theirs:
                label = names.get(field, field)
                if field.endswith("sha256"):
                    out.append(f"other {label} than the policy's")
                else:
                    out.append(f"{label} {mine!r}, the policy has {theirs!r}")
        return out


def expected_manifest(
    policy,
    device: str,
    num_inference_steps: int,
    batch_size: int,
    package_sha256: str = "",
    weights_sha256: str | None = None,
    guided: bool = False,
) -> Manifest:
    """The manifest an artefact of this policy for ``device``, K, batch size and program must carry
    (``weights_sha256``: the policy's :func:`weights_fingerprint`, when already computed)."""
    program = policy.sampler_program(policy, num_inference_steps, guided)
    return Manifest(
        format=FORMAT_VERSION,
        policy=policy.name,
        device=device,
        num_inference_steps=num_inference_steps,
        torch=torch.__version__,
        dtype=str(next(policy.parameters()).dtype).removeprefix("torch."),
        weights_sha256=weights_sha256 or weights_fingerprint(policy),
        config_sha256=config_fingerprint(policy.config),
        package_sha256=package_sha256,
        inputs=program.input_names(),
        batch_size=batch_size,
        guided=guided,
    )


def export_sampler(
    policy,
    directory: str | Path,
    num_inference_steps: int,
    device: str = "cpu",
    batch_size: int = 1,
    guided: bool = False,
) -> Path:
    """Export and compile the sampler of ``policy`` (the guided program with ``guided``) for K steps
    on ``device`` at one batch size; write the artefact under ``directory/exported_sampler/``
    (replacing one of the same program, device, K and batch size) and return its directory.

    The artefact is built in a temporary directory next to its destination and moved into place
    when complete, so an interrupted export leaves any earlier artefact as it was.

    Raises:
        ValueError: K < 1, ``batch_size`` < 1, a device type other than cpu / cuda, a policy
            that reads a point cloud (``point_cloud_key``; not supported by the artefacts), or
            ``guided`` with a solver other than Euler.
        RuntimeError: CUDA requested but not available.
    """
    if num_inference_steps < 1:
        raise ValueError(f"num_inference_steps (K) must be >= 1, got {num_inference_steps}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if device not in ("cpu", "cuda"):
        raise ValueError(f"device must be 'cpu' or 'cuda', got {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        raise RuntimeError("--device cuda: torch sees no CUDA device on this machine")
    if policy.config.point_cloud_key is not None:
        raise ValueError(
            f"this policy reads the point cloud '{policy.config.point_cloud_key}' (point_cloud_key), "
            "which exported samplers do not take: run it eagerly, or with compile_sampler=true"
        )
    if guided:
        check_rtc_solver(policy.config.solver)
    policy = policy.to(device).eval()
    program = policy.sampler_program(policy, num_inference_steps, guided).to(device).eval()
    example = program.example_inputs(batch_size, torch.device(device))
    with torch.no_grad():
        exported = torch.export.export(program, example, strict=False)
    final = Path(directory) / EXPORT_DIR / artefact_name(device, num_inference_steps, batch_size, guided)
    final.parent.mkdir(parents=True, exist_ok=True)
    staging = _staging_dir(final)
    try:
        package = staging / PACKAGE_FILE
        torch._inductor.aoti_compile_and_package(
            exported, package_path=str(package), inductor_configs=inductor_config(device, guided)
        )
        manifest = expected_manifest(
            policy, device, num_inference_steps, batch_size, file_fingerprint(package), guided=guided
        )
        manifest.write(staging / MANIFEST_FILE)
        _replace_directory(staging, final)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return final


def _staging_dir(final: Path) -> Path:
    """A fresh, readable directory next to ``final``, for building its replacement."""
    staging = Path(tempfile.mkdtemp(prefix=f".{final.name}-", dir=final.parent))
    staging.chmod(0o755)
    return staging


def _replace_directory(new: Path, final: Path) -> None:
    """Move ``new`` to ``final``; a previous ``final`` is removed only once ``new`` is in place."""
    old = None
    if final.exists():
        old = final.with_name(f".{final.name}-old-{os.getpid()}")
        os.replace(final, old)
    os.replace(new, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


class _Runner:
    """One loaded package: calls it with the inputs its manifest names."""

    def __init__(self, package: Path, manifest: Manifest):
        self.manifest = manifest
        self.package = package
        # The C++ loader directly: importing torch._inductor's Python side takes seconds.
        loader_cls = torch._C._aoti.AOTIModelPackageLoader
        self._loader = loader_cls(str(package), "model", False, 1, -1)
        self._run: Callable[[list[Tensor]], list[Tensor]] = self._loader.run

    def __call__(self, inputs: list[Tensor]) -> Tensor:
        return self._run(inputs)[0]


class ExportedSamplers:
    """The artefacts a policy may use, by :class:`ArtefactKey`, with the staleness checks of the
    module docstring."""

    def __init__(self, policy, runners: dict[ArtefactKey, _Runner]):
        self._policy = policy
        self._runners = runners
        self._versions = self._parameter_versions()
        self._reported_misses: set[ArtefactKey] = set()

    @classmethod
    def load(cls, policy, directory: str | Path) -> ExportedSamplers | None:
        """The matching artefacts under ``directory/exported_sampler`` (None when there is no such
        directory). Each refused artefact is logged with its reason."""
        root = Path(directory) / EXPORT_DIR
        if not root.is_dir():
            return None
        runners = {}
        weights = weights_fingerprint(policy)
        for artefact in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
            runner = _load_artefact(policy, artefact, weights)
            if runner is not None:
                runners[runner.manifest.key] = runner
        return cls(policy, runners)

    def keys(self) -> list[ArtefactKey]:
        """What every artefact in use serves."""
        return sorted(self._runners)

    def get(
        self, device: torch.device, num_inference_steps: int, batch_size: int, guided: bool = False
    ) -> Callable[[list[Tensor]], Tensor] | None:
        """A callable taking the program's inputs (a list in the order of its ``input_names``) and
        returning the chunk, for this device, K, batch size and program; or None (logged once per
        key) when there is none or it no longer matches."""
        key = ArtefactKey(device.type, num_inference_steps, batch_size, guided)
        if self._versions != self._parameter_versions():
            self.verify()
        runner = self._runners.get(key)
        if runner is None:
            if key not in self._reported_misses and self._runners:
                self._reported_misses.add(key)
                have = ", ".join(k.describe() for k in self.keys())
                logger.warning(
                    "%s: no exported sampler for %s (exported: %s); sampling eagerly",
                    self._policy.name, key.describe(), have,
                )  # fmt: skip
            return None
        return partial(self._call, runner)

    @staticmethod
    def _call(runner: _Runner, inputs: list[Tensor]) -> Tensor:
        if len(inputs) != len(runner.manifest.inputs):
            raise ValueError(
                f"the exported sampler {runner.package} takes {list(runner.manifest.inputs)}, "
                f"got {len(inputs)} tensors"
            )
        return runner([t.contiguous() for t in inputs])

    def verify(self) -> None:
        """Re-hash the weights; drop (with a log line) every artefact built from other weights."""
        fingerprint = weights_fingerprint(self._policy)
        for key, runner in list(self._runners.items()):
            if runner.manifest.weights_sha256 != fingerprint:
                logger.warning(
                    "%s: the policy's weights changed since the exported sampler %s was "
                    "loaded; not using it (%s samples eagerly)",
                    self._policy.name, runner.package, key.describe(),
                )  # fmt: skip
                del self._runners[key]
        self._versions = self._parameter_versions()

    def save(self, directory: str | Path) -> None:
        """Copy the artefacts still in use to ``directory/exported_sampler`` (``save_pretrained``)."""
        if self._versions != self._parameter_versions():
            self.verify()
        for key, runner in self._runners.items():
            target = Path(directory) / EXPORT_DIR / artefact_name(*key)
            if target.resolve() == runner.package.parent.resolve():
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            staging = _staging_dir(target)
            try:
                for name in (PACKAGE_FILE, MANIFEST_FILE):
                    shutil.copy2(runner.package.parent / name, staging / name)
                _replace_directory(staging, target)
            finally:
                shutil.rmtree(staging, ignore_errors=True)

    def _parameter_versions(self) -> tuple[int, ...]:
        return tuple(t._version for t in _tensors(self._policy))


def _tensors(module: nn.Module) -> Iterable[Tensor]:
    yield from module.parameters()
    yield from module.buffers()


def _load_artefact(policy, artefact: Path, weights_sha256: str) -> _Runner | None:
    """The runner of one artefact directory, or None with a log line saying why it is refused."""

    def refuse(why: str) -> None:
        logger.warning(
            "%s: not using the exported sampler %s: %s; sampling eagerly", policy.name, artefact, why
        )

    try:
        manifest = Manifest.read(artefact / MANIFEST_FILE)
    except ValueError as e:
        refuse(str(e))
        return None
    if manifest.format != FORMAT_VERSION:
        refuse(f"format {manifest.format}, this version reads format {FORMAT_VERSION}")
        return None
    if manifest.device == "cuda" and not torch.cuda.is_available():
        refuse("it was exported for CUDA and torch sees no CUDA device")
        return None
    expected = expected_manifest(
        policy,
        manifest.device,
        manifest.num_inference_steps,
        manifest.batch_size,
        weights_sha256=weights_sha256,
        guided=manifest.guided,
    )
    differences = manifest.differences(expected)
    if differences:
        refuse("; ".join(differences) + f" (re-export with `actionflow-export {artefact.parent.parent}`)")
        return None
    package = artefact / PACKAGE_FILE
    if not package.is_file():
        refuse(f"{package} is missing")
        return None
    if file_fingerprint(package) != manifest.package_sha256:
        refuse(f"{package} is not the file its manifest describes")
        return None
    try:
        return _Runner(package, manifest)
    except (RuntimeError, AttributeError) as e:
        refuse(f"the package does not load: {e}")
        return None


class ExportedSamplerLoading:
    """Policy mixin: ``from_pretrained`` attaches the checkpoint's exported samplers
    (:meth:`attach_exported_samplers`) and ``save_pretrained`` carries those in use. The policy
    sets ``exported_samplers = None`` in its ``__init__`` and names its ``sampler_program``."""

    exported_samplers: ExportedSamplers | None

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path, **kwargs):
        """LeRobot's ``from_pretrained``, then the checkpoint's exported samplers, if any."""
        policy = super().from_pretrained(pretrained_name_or_path, **kwargs)
        hub = {k: kwargs[k] for k in ("revision", "cache_dir", "token", "local_files_only") if k in kwargs}
        policy.attach_exported_samplers(pretrained_name_or_path, **hub)
        return policy

    def attach_exported_samplers(self, pretrained_name_or_path, **hub_kwargs) -> None:
        """Use the exported samplers stored with a checkpoint (a local ``pretrained_model``
        directory or a Hub repository) that match this policy's weights and configuration;
        refused ones are logged (module docstring)."""
        directory = Path(pretrained_name_or_path)
        if not directory.is_dir():
            directory = _download_exported(self.name, str(pretrained_name_or_path), hub_kwargs)
        self.exported_samplers = ExportedSamplers.load(self, directory) if directory is not None else None

    def _save_pretrained(self, save_directory: Path, state_dict=None) -> None:
        super()._save_pretrained(save_directory, state_dict)
        if self.exported_samplers is not None and state_dict is None:
            self.exported_samplers.save(save_directory)


def _download_exported(policy_name: str, repo_id: str, hub_kwargs: dict) -> Path | None:
    """The local snapshot of a Hub repository's exported samplers, or None (logged) when the Hub
    cannot provide them."""
    try:
        return Path(snapshot_download(repo_id, allow_patterns=[f"{EXPORT_DIR}/*"], **hub_kwargs))
    except (HfHubHTTPError, OSError, ValueError) as e:
        logger.info(
            "%s: no exported samplers fetched from %s (%s); sampling eagerly", policy_name, repo_id, e
        )
        return None
