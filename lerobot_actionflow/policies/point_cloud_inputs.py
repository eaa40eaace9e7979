"""Point-cloud inputs shared by both policies: the config fields' checks and the feature's.

A policy reads a cloud only when its config names it (``point_cloud_key``, e.g.
``observation.point_cloud``): an input feature of shape ``(M, 3)``, points ``[x, y, z]`` in
metres in the robot base/world frame (the frame of the poses and actions), stored as float16
or float32 and cast to the policy's dtype on input. The cloud is never normalised by the
processors: its coordinates are metres, and per-element statistics of an FPS-ordered cloud
would be meaningless (and, for ActionFlow, would break equivariance).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from lerobot_actionflow.policies.config_errors import require, require_ints
from lerobot_actionflow.schema import POINT_DIM


def validate_point_cloud_fields(config: Any, int_fields: Iterable[str]) -> None:
    """``point_cloud_key`` is None or an ``observation.*`` key; the size fields are ints >= 1."""
    key = config.point_cloud_key
    require(
        key is None or (isinstance(key, str) and key.startswith("observation.")),
        f"`point_cloud_key` must be None or an observation feature key such as "
        f"'observation.point_cloud', got {key!r}",
    )
    require_ints(config, tuple(int_fields))


def check_point_cloud_feature(features: Mapping[str, Any] | None, key: str | None, min_points: int) -> None:
    """The feature ``key`` exists among ``features`` with shape ``(M, 3)``, ``M >= min_points``.

    Raises:
        ValueError: naming the feature, the expected shape and what the input features hold.
    """
    if key is None:
        return
    features = features or {}
    if key not in features:
        raise ValueError(
            f"point_cloud_key is '{key}', but the input features have no such feature "
            f"({sorted(features)}); record the dataset with point clouds (actionflow-collect "
            f"--point-cloud) or leave point_cloud_key unset"
        )
    shape = tuple(features[key].shape)
    if len(shape) != 2 or shape[1] != POINT_DIM:
        raise ValueError(f"point-cloud feature '{key}' must have shape (M, {POINT_DIM}), got {shape}")
    if shape[0] < min_points:
        raise ValueError(
            f"point-cloud feature '{key}' has M={shape[0]} points, fewer than the {min_points} the "
            f"policy reads (point_cloud_prefix, or at least its groups and group size)"
        )
