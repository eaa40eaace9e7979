"""Strict checkpoint loading for this package's policies.

LeRobot's ``PreTrainedPolicy.from_pretrained`` loads weights with ``strict=False`` by default:
a checkpoint whose architecture differs from the config (``--policy.num_layers=3`` on a 2-layer
checkpoint) loads with a logged warning, and the missing layers keep their random initial values.
:class:`StrictLoading` makes ``strict=True`` the default for our policies (LeRobot's factory and
``lerobot-eval`` call ``from_pretrained`` without ``strict``) and, when strict, compares the file
with the model before loading, so that the error lists every parameter that differs: missing from
the file, unexpected in it, or of another shape. ``strict=False`` remains available to callers who
load a partial checkpoint on purpose.
"""

from __future__ import annotations

from safetensors import safe_open
from torch import nn


class CheckpointMismatchError(ValueError):
    """The weights in a checkpoint do not fit the policy built from the config."""


def _listing(title: str, items: list[str], limit: int = 12) -> str:
    shown = "\n".join(f"    {item}" for item in items[:limit])
    more = f"\n    ... and {len(items) - limit} more" if len(items) > limit else ""
    return f"  {title} ({len(items)}):\n{shown}{more}"


def checkpoint_mismatches(model: nn.Module, model_file: str) -> tuple[list[str], list[str], list[str]]:
    """``(missing, unexpected, shape mismatches)`` between ``model`` and a safetensors file,
    read from the file's header (no weights are loaded). A parameter stored once for several
    names (tied weights; safetensors keeps one name) is not reported missing."""
    with safe_open(model_file, framework="pt") as f:
        stored = {key: tuple(f.get_slice(key).get_shape()) for key in f.keys()}
    expected = model.state_dict()
    missing = [k for k in expected if k not in stored]
    if missing:
        # Tied weights: a name is covered when another name of the same storage is stored.
        storage = {k: (t.data_ptr(), tuple(t.shape)) for k, t in expected.items() if t.numel()}
        stored_storages = {storage[k] for k in stored if k in storage}
        missing = [k for k in missing if k not in storage or storage[k] not in stored_storages]
    unexpected = [k for k in stored if k not in expected]
    shapes = [
        f"{k}: checkpoint {stored[k]}, model {tuple(expected[k].shape)}"
        for k in expected
        if k in stored and stored[k] != tuple(expected[k].shape)
    ]
    return missing, unexpected, shapes


class StrictLoading:
    """Mixin for a ``PreTrainedPolicy`` subclass (put it first in the bases): strict loading."""

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path, *, strict: bool = True, **kwargs):
        """LeRobot's ``from_pretrained`` with ``strict=True`` by default.

        Raises:
            CheckpointMismatchError: (strict) the checkpoint's weights do not match the model
                the config describes; the message lists the parameters that differ.
        """
        return super().from_pretrained(pretrained_name_or_path, strict=strict, **kwargs)

    @classmethod
    def _load_as_safetensor(cls, model, model_file: str, map_location: str, strict: bool):
        if strict:
            missing, unexpected, shapes = checkpoint_mismatches(model, model_file)
            if missing or unexpected or shapes:
                parts = [
                    _listing(title, items)
                    for title, items in (
                        ("missing from the checkpoint", missing),
                        ("in the checkpoint but not in the model", unexpected),
                        ("of a different shape", shapes),
                    )
                    if items
                ]
                raise CheckpointMismatchError(
                    f"the weights in {model_file} do not match the {cls.name} policy built from its "
                    "config; was an architecture option (e.g. --policy.num_layers, --policy.dim) "
                    "changed from the checkpoint's? Parameters that differ:\n" + "\n".join(parts)
                )
        return super()._load_as_safetensor(model, model_file, map_location, strict)
