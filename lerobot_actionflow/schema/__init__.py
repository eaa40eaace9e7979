"""The dataset / env / policy contract: feature names, shapes and the action layout.

One schema, shared by the envs (observations they emit, actions they accept), the datasets
(what collection and conversion write) and the policies (what they read and produce). No
LeRobot import: these are plain names and torch helpers.

* ``observation.poses`` float32 ``(N, 7)``: entity poses ``[x, y, z, qw, qx, qy, qz]`` in the
  robot base/world frame, row 0 the end-effector, then the task's objects in a fixed order.
* ``observation.state`` float32 ``(11,)``: ``[eef xyz (3), eef rot6d (6), gripper qpos (2)]``.
* ``observation.environment_state`` float32 ``(9 (N - 1),)``: object poses ``[xyz, rot6d]``.
* ``observation.images.<camera>``: optional, e.g. ``wrist``, ``agentview``.
* ``action`` float32 ``(10,)``: absolute EEF target ``[x, y, z, rot6d (6), gripper]``, gripper
  in ``[-1, 1]`` (-1 open, +1 closed).
"""

from __future__ import annotations

import torch

from lerobot_actionflow.geometry.se3 import pose9_to_rp, rp_to_pose9

POSES_KEY = "observation.poses"
STATE_KEY = "observation.state"
ENV_STATE_KEY = "observation.environment_state"
IMAGES_PREFIX = "observation.images."
ACTION_KEY = "action"

ACTION_DIM = 10
STATE_DIM = 11
#: Indices of the gripper finger positions in ``observation.state``.
STATE_GRIPPER_INDICES = (9, 10)


def action_to_pose(action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(..., 10)`` action -> rotation ``(..., 3, 3)`` (Gram-Schmidt), position ``(..., 3)``,
    gripper ``(...)``."""
    if action.shape[-1] != ACTION_DIM:
        raise ValueError(
            f"'{ACTION_KEY}' must have last dimension {ACTION_DIM} [x y z rot6d gripper], "
            f"got {tuple(action.shape)}"
        )
    r, p = pose9_to_rp(action[..., :9])
    return r, p, action[..., 9]


def pose_to_action(r: torch.Tensor, p: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`action_to_pose`: ``(..., 3, 3), (..., 3), (...)`` -> ``(..., 10)``."""
    return torch.cat((rp_to_pose9(r, p), g[..., None]), -1)
