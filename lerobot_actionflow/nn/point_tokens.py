"""Point-cloud tokens for ActionFlow: local groups of points as posed tokens (SE(3)-invariant).

From a cloud ``X = {x_j} (B, M, 3)`` (world/base frame, metres) and the reference rotation
``R (B, 3, 3)`` (the end-effector's at the latest observation step):

1. Group centres ``c_1..c_G``: farthest-point sampling that starts at index 0,
   ``i_1 = 0``, ``i_{g+1} = argmax_j min_{l <= g} |x_j - x_{i_l}|`` (ties: the lowest index).
   The choice depends only on distances and on the row order, so for a rigid motion
   ``x_j -> A x_j + b`` of the cloud (rows kept in order) the same rows are chosen: the centres
   move with the scene.
2. Groups: the ``k`` nearest neighbours of each centre (the centre itself included), again by
   distance only.
3. Each group is a token posed at ``(R, c_g)``; its feature is a PointNet over the neighbour
   offsets in the token frame, ``s R^T (x_j - c_g)`` (``s`` the policy's translation scale):
   a shared MLP per neighbour, then a max over the ``k`` neighbours, then a linear layer.

Under ``(R, x) -> (A R, A x + b)`` the offsets ``R^T A^T A (x_j - c_g)`` are unchanged, so the
features are invariant and the token poses transform rigidly with the scene: the tokens can join
the IPA transformer's observation tokens without breaking its invariance. Group selection is
not differentiable (indices); the features are.
"""

from __future__ import annotations

import torch
from torch import nn

from lerobot_actionflow.nn.pointnet import PointNetEncoder
from lerobot_actionflow.schema import POINT_DIM


def farthest_point_indices(points: torch.Tensor, num_samples: int) -> torch.Tensor:
    """Indices ``(B, G)`` of a farthest-point sample of ``points (B, M, 3)``, starting at row 0.

    Deterministic (no random start), batched; ``G = num_samples <= M``. When fewer than ``G``
    distinct points exist, the remaining picks repeat row 0 (every distance is then 0).
    """
    b, m, _ = points.shape
    if not 1 <= num_samples <= m:
        raise ValueError(f"farthest-point sampling of {num_samples} centres needs 1..M points, got M={m}")
    rows = torch.arange(b, device=points.device)
    chosen = torch.zeros(b, num_samples, dtype=torch.long, device=points.device)
    dist = torch.full((b, m), torch.inf, dtype=points.dtype, device=points.device)
    last = torch.zeros(b, dtype=torch.long, device=points.device)
    for i in range(1, num_samples):
        d = (points - points[rows, last][:, None]).square().sum(-1)
        dist = torch.minimum(dist, d)
        last = dist.argmax(-1)  # argmax returns the first maximal index: ties go to the lowest
        chosen[:, i] = last
    return chosen


def knn_indices(points: torch.Tensor, centres: torch.Tensor, k: int) -> torch.Tensor:
    """Indices ``(B, G, k)`` of the ``k`` nearest rows of ``points (B, M, 3)`` to each of
    ``centres (B, G, 3)``, nearest first (squared distances from coordinate differences, not
    the ``|a|^2 - 2ab + |b|^2`` expansion, whose cancellation would reorder close neighbours)."""
    m = points.shape[1]
    if not 1 <= k <= m:
        raise ValueError(f"groups of k={k} nearest points need 1..M points, got M={m}")
    d = (centres[:, :, None] - points[:, None]).square().sum(-1)  # (B, G, M)
    return d.topk(k, dim=-1, largest=False, sorted=True).indices


def group_points(points: torch.Tensor, num_groups: int, group_size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Centres ``(B, G, 3)`` (farthest-point sample from row 0) and their neighbourhoods
    ``(B, G, k, 3)`` (the ``k`` nearest points of each centre)."""
    if points.ndim != 3 or points.shape[-1] != POINT_DIM:
        raise ValueError(f"a point cloud must have shape (B, M, {POINT_DIM}), got {tuple(points.shape)}")
    with torch.no_grad():
        centre_idx = farthest_point_indices(points, num_groups)
    b = points.shape[0]
    rows = torch.arange(b, device=points.device)[:, None]
    centres = points[rows, centre_idx]
    with torch.no_grad():
        nbr_idx = knn_indices(points, centres, group_size)
    neighbours = points[rows[:, :, None], nbr_idx]
    return centres, neighbours


class PointGroupTokenizer(nn.Module):
    """A point cloud -> ``G`` posed group tokens (module docstring).

    Args:
        num_groups: ``G`` tokens; group_size: ``k`` neighbours per token.
        width: hidden width of the per-point MLP; dim: output feature size (the transformer's).
    """

    def __init__(self, num_groups: int, group_size: int, width: int, dim: int):
        super().__init__()
        for name, v in (("num_groups", num_groups), ("group_size", group_size), ("width", width)):
            if int(v) < 1:
                raise ValueError(f"point tokens: {name} must be >= 1, got {v}")
        self.num_groups, self.group_size = int(num_groups), int(group_size)
        self.encoder = PointNetEncoder(width, dim)  # per group: max over its k neighbours

    def forward(
        self, points: torch.Tensor, r_ref: torch.Tensor, scale: float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``points (B, M, 3)``, ``r_ref (B, 3, 3)`` -> features ``(B, G, dim)`` and token
        positions (the centres) ``(B, G, 3)``; every token's rotation is ``r_ref``."""
        centres, neighbours = group_points(points, self.num_groups, self.group_size)
        # R^T (x_j - c): row-vector form (x_j - c)^T R.
        local = (neighbours - centres[:, :, None]) @ r_ref[:, None] * scale
        return self.encoder(local), centres
