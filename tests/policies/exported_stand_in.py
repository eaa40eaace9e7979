"""A stand-in for a compiled exported-sampler package: the manifest checks of
:mod:`lerobot_actionflow.policies.exported` run for real, the package is never loaded."""

from dataclasses import asdict
from typing import ClassVar

import torch

from lerobot_actionflow.policies import exported as ex

#: What the stand-in package returns: no sampler of a real policy gives these actions.
MARK = 7.0


class StandInRunner:
    """Replaces the loaded package (``monkeypatch.setattr(ex, "_Runner", StandInRunner)``):
    records its inputs' shapes and answers ``(B, H, action_dim)`` of :data:`MARK`, with B and H
    read from its last input (``(B, H, ...)`` for every program)."""

    calls: ClassVar[list] = []
    action_dim: ClassVar[int] = 10

    def __init__(self, package, manifest):
        self.package, self.manifest = package, manifest

    def __call__(self, inputs):
        StandInRunner.calls.append([t.shape for t in inputs])
        batch, horizon = inputs[-1].shape[:2]
        return torch.full((batch, horizon, StandInRunner.action_dim), MARK)


def write_stand_in(policy, path, k, batch_size=2, guided=False, **manifest_changes):
    """A stand-in artefact under ``path`` whose manifest matches ``policy`` (but for
    ``manifest_changes``)."""
    artefact = path / ex.EXPORT_DIR / ex.artefact_name("cpu", k, batch_size, guided)
    artefact.mkdir(parents=True, exist_ok=True)
    (artefact / ex.PACKAGE_FILE).write_bytes(b"stand-in package")
    package_sha256 = ex.file_fingerprint(artefact / ex.PACKAGE_FILE)
    manifest = ex.expected_manifest(policy, "cpu", k, batch_size, package_sha256, guided=guided)
    fields = {**asdict(manifest), **manifest_changes}
    ex.Manifest(**fields).write(artefact / ex.MANIFEST_FILE)
    return artefact


def used_artefact(actions) -> bool:
    return bool((actions == MARK).all())
