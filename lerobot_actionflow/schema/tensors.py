"""Torch helpers on the schema's action layout (:mod:`lerobot_actionflow.schema`)."""

from __future__ import annotations

import torch

from lerobot_actionflow.geometry.se3 import pose9_to_rp, rp_to_pose9
from lerobot_actionflow.schema import ACTION_DIM, ACTION_GRIPPER_INDEX, ACTION_KEY, POSE9_DIM


def action_to_pose(action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(..., 10)`` action -> rotation ``(..., 3, 3)`` (Gram-Schmidt), position ``(..., 3)``,
    gripper ``(...)``."""
    if action.shape[-1] != ACTION_DIM:
        raise ValueError(
            f"'{ACTION_KEY}' must have last dimension {ACTION_DIM} [x y z rot6d gripper], "
            f"got {tuple(action.shape)}"
        )
    r, p = pose9_to_rp(action[..., :POSE9_DIM])
    return r, p, action[..., ACTION_GRIPPER_INDEX]


def pose_to_action(r: torch.Tensor, p: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`action_to_pose`: ``(..., 3, 3), (..., 3), (...)`` -> ``(..., 10)``."""
    return torch.cat((rp_to_pose9(r, p), g[..., None]), -1)
