"""The continuous 6D rotation representation (Zhou et al., 2019).

A rotation is stored as its first two columns, ``(r00, r10, r20, r01, r11, r21)``, and
recovered by Gram-Schmidt: ``b1 = a1/|a1|``, ``b2 = (a2 - (b1.a2) b1)/|...|``,
``b3 = b1 x b2``. The map is continuous and defined for any pair of non-parallel vectors,
which makes it a good regression target; this is the rotation part of the project's
10-D action ``[x, y, z, rot6d, gripper]``.
"""

from __future__ import annotations

import torch


def matrix_to_rotation_6d(r: torch.Tensor) -> torch.Tensor:
    """First two columns, concatenated: ``(..., 3, 3) -> (..., 6)``."""
    if r.ndim < 2 or r.shape[-2:] != (3, 3):
        raise ValueError(f"matrix_to_rotation_6d expects (..., 3, 3), got shape {tuple(r.shape)}")
    return torch.cat((r[..., :, 0], r[..., :, 1]), -1)


def rotation_6d_to_matrix(d6: torch.Tensor, eps: float | None = None) -> torch.Tensor:
    """Gram-Schmidt: ``(..., 6) -> (..., 3, 3)`` with columns ``b1, b2, b3``.

    Args:
        d6: two 3-vectors, not necessarily orthonormal.
        eps: lower bound on the norms divided by (default: the dtype's ``tiny``); degenerate
            input (a zero or parallel pair) gives a non-rotation rather than NaN, which
            :func:`lerobot_actionflow.geometry.validation.check_rotation_matrix` then reports.
    """
    if d6.shape[-1] != 6:
        raise ValueError(f"rotation_6d_to_matrix expects (..., 6), got shape {tuple(d6.shape)}")
    eps = torch.finfo(d6.dtype).tiny if eps is None else eps
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = a1 / torch.linalg.vector_norm(a1, dim=-1, keepdim=True).clamp_min(eps)
    a2 = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    b2 = a2 / torch.linalg.vector_norm(a2, dim=-1, keepdim=True).clamp_min(eps)
    b3 = torch.linalg.cross(b1, b2, dim=-1)
    return torch.stack((b1, b2, b3), -1)
