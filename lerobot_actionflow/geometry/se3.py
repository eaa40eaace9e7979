"""Rigid transforms SE(3) as ``(R, p)`` pairs, and the project's pose layouts.

A transform ``T = (R, p)`` maps a point ``x`` to ``R x + p``. Composition is
``T1 T2 = (R1 R2, R1 p2 + p1)`` and the inverse is ``(R^T, -R^T p)``. Rotations are
``(..., 3, 3)``, translations ``(..., 3)``; all functions broadcast over leading dimensions.

Pose layouts used across the project (datasets, envs, policies):

* ``pose7``: ``[x, y, z, qw, qx, qy, qz]`` (scalar-first quaternion), the layout of
  ``observation.poses`` rows;
* ``pose9``: ``[x, y, z, rot6d]`` (first two rotation columns), the pose part of the
  10-D ``action``.
"""

from __future__ import annotations

import torch

from lerobot_actionflow.geometry.quaternion import matrix_to_quaternion, quaternion_to_matrix
from lerobot_actionflow.geometry.rotation6d import matrix_to_rotation_6d, rotation_6d_to_matrix


def compose(
    r1: torch.Tensor, p1: torch.Tensor, r2: torch.Tensor, p2: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``T1 T2 = (R1 R2, R1 p2 + p1)``."""
    return r1 @ r2, (r1 @ p2[..., None]).squeeze(-1) + p1


def inverse(r: torch.Tensor, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``T^-1 = (R^T, -R^T p)``."""
    rt = r.transpose(-1, -2)
    return rt, -(rt @ p[..., None]).squeeze(-1)


def apply(r: torch.Tensor, p: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``T x = R x + p`` for points ``x`` ``(..., 3)``."""
    return (r @ x[..., None]).squeeze(-1) + p


def relative(
    r_ref: torch.Tensor, p_ref: torch.Tensor, r: torch.Tensor, p: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``T_ref^-1 T``: the pose ``T`` expressed in the frame ``T_ref``."""
    ri, pi = inverse(r_ref, p_ref)
    return compose(ri, pi, r, p)


def to_matrix(r: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """Homogeneous ``(..., 4, 4)`` matrix of ``(R, p)``."""
    top = torch.cat((r, p[..., None]), -1)
    bottom = torch.zeros(*top.shape[:-2], 1, 4, dtype=r.dtype, device=r.device)
    bottom[..., 0, 3] = 1
    return torch.cat((top, bottom), -2)


def from_matrix(m: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(R, p)`` of a homogeneous ``(..., 4, 4)`` matrix."""
    if m.ndim < 2 or m.shape[-2:] != (4, 4):
        raise ValueError(f"from_matrix expects (..., 4, 4), got shape {tuple(m.shape)}")
    return m[..., :3, :3], m[..., :3, 3]


def pose7_to_rp(pose: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``[x, y, z, qw, qx, qy, qz]`` ``(..., 7)`` to ``(R, p)``."""
    if pose.shape[-1] != 7:
        raise ValueError(f"expected poses (..., 7) [x y z qw qx qy qz], got {tuple(pose.shape)}")
    return quaternion_to_matrix(pose[..., 3:]), pose[..., :3]


def rp_to_pose7(r: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """``(R, p)`` to ``[x, y, z, qw, qx, qy, qz]`` with ``qw >= 0``."""
    return torch.cat((p, matrix_to_quaternion(r)), -1)


def pose9_to_rp(pose: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``[x, y, z, rot6d]`` ``(..., 9)`` to ``(R, p)`` (Gram-Schmidt on the 6D part)."""
    if pose.shape[-1] != 9:
        raise ValueError(f"expected poses (..., 9) [x y z rot6d], got {tuple(pose.shape)}")
    return rotation_6d_to_matrix(pose[..., 3:]), pose[..., :3]


def rp_to_pose9(r: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """``(R, p)`` to ``[x, y, z, rot6d]``."""
    return torch.cat((p, matrix_to_rotation_6d(r)), -1)
