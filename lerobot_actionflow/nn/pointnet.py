"""PointNet global encoder (Qi et al. 2017, without the input transform nets): a shared MLP per
point, then a max over the points.

    f(X) = W_out max_j MLP(s x_j),   X = {x_j} (..., M, 3)  ->  (..., D)

Points enter in the frame they are given in (for ``euclidean_flow``: the world/base frame,
times a fixed scale ``s``), so the feature is invariant to the order of the points but not to a
rigid motion of the scene: it is the non-equivariant baseline's cloud encoder.
"""

from __future__ import annotations

import torch
from torch import nn

from lerobot_actionflow.schema import POINT_DIM


class PointNetEncoder(nn.Module):
    """``(..., M, 3)`` -> ``(..., out_dim)``; ``width`` hidden units per point."""

    def __init__(self, width: int = 128, out_dim: int = 128, scale: float = 1.0):
        super().__init__()
        if width < 1 or out_dim < 1 or not scale > 0:
            raise ValueError(
                f"PointNet needs width, out_dim >= 1 and scale > 0, got {width}, {out_dim}, {scale}"
            )
        self.scale = float(scale)
        self.out_dim = int(out_dim)
        self.point_mlp = nn.Sequential(
            nn.Linear(POINT_DIM, width),
            nn.GELU(),
            nn.Linear(width, width),
            nn.GELU(),
            nn.Linear(width, width),
        )
        self.out = nn.Sequential(nn.LayerNorm(width), nn.Linear(width, out_dim))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        if points.shape[-1] != POINT_DIM or points.ndim < 2:
            raise ValueError(f"PointNet input must be (..., M, {POINT_DIM}), got {tuple(points.shape)}")
        return self.out(self.point_mlp(points * self.scale).amax(dim=-2))
