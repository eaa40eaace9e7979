"""Invariant Point Attention (IPA) with full SE(3) frames (AlphaFold2; ActionFlow App. D).

Every token ``i`` carries a feature ``f_i`` (``(B, L, C)``) and a frame ``T_i = (R_i, p_i)``
(``(B, L, 3, 3)``, ``(B, L, 3)``). Per head ``h``:

* scalar queries/keys/values ``q_i, k_i, v_i in R^c`` = Linear(f_i);
* local query/key points ``q_i^p, k_i^p`` and value points ``v_i^p in R^3`` = Linear(f_i),
  placed in the world by the token's frame: ``T_i x = R_i x + p_i``;
* attention ``a_ij = softmax_j( w_L q_i.k_j - (gamma_h w_C / 2) sum_p |T_i q_i^p - T_j k_j^p|^2 )``
  with ``w_L = 1/sqrt(3c)``, ``w_C = sqrt(2 / (9 N_qp))`` and ``gamma_h = softplus(.)`` a learned
  per-head point weight (Alg. 3 / AF2 Alg. 22 without the pair bias);
* outputs ``o_i = sum_j a_ij v_j`` and ``o_i^p = T_i^{-1} (sum_j a_ij T_j v_j^p)``, brought back into
  token ``i``'s own frame, with their norms ``|o_i^p|``; ``f_i' = Linear(concat(o, o^p, |o^p|))``.

Distances between world points and points expressed back in the local frame are unchanged by
a global ``T``: ``T T_i x - T T_j y`` has the norm of ``T_i x - T_j y``, and
``(T T_i)^{-1} T y = T_i^{-1} y``. So the output features are SE(3)-invariant.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


class InvariantPointAttention(nn.Module):
    """IPA over a set of posed tokens.

    Args:
        dim: feature size ``C``.
        num_heads: ``N_head``.
        head_dim: scalar channels per head ``c``.
        num_query_points: ``N_qp`` query/key points per head.
        num_value_points: ``N_pv`` value points per head.
    """

    def __init__(
        self,
        dim: int,
        num_heads: int = 8,
        head_dim: int = 16,
        num_query_points: int = 4,
        num_value_points: int = 8,
    ):
        super().__init__()
        self.num_heads, self.head_dim = num_heads, head_dim
        self.num_query_points, self.num_value_points = num_query_points, num_value_points
        self.to_qkv = nn.Linear(dim, 3 * num_heads * head_dim, bias=False)
        self.to_qk_points = nn.Linear(dim, 2 * num_heads * num_query_points * 3)
        self.to_v_points = nn.Linear(dim, num_heads * num_value_points * 3)
        # softplus(0.5413) = 1: every head starts with unit point weight.
        self.point_weight = nn.Parameter(torch.full((num_heads,), math.log(math.e - 1)))
        self.w_l = 1.0 / math.sqrt(3 * head_dim)
        self.w_c = math.sqrt(2.0 / (9 * num_query_points))
        out_in = num_heads * (head_dim + num_value_points * 4)
        self.to_out = nn.Linear(out_in, dim)

    def forward(
        self, f: torch.Tensor, r: torch.Tensor, p: torch.Tensor, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Args:
            f: features ``(B, L, C)``; r: ``(B, L, 3, 3)``; p: ``(B, L, 3)``.
            mask: optional boolean ``(B, L, L)`` or ``(L, L)``, True where token i may attend j.
        Returns:
            ``(B, L, C)`` invariant updates.
        """
        b, n, _ = f.shape
        h, c, pq, pv = self.num_heads, self.head_dim, self.num_query_points, self.num_value_points
        q, k, v = self.to_qkv(f).view(b, n, 3, h, c).unbind(2)  # (B, L, H, c)

        def to_world(x: torch.Tensor, npts: int) -> torch.Tensor:
            x = x.view(b, n, h * npts, 3)
            return torch.einsum("blij,blmj->blmi", r, x) + p[:, :, None, :]

        qk_pts = self.to_qk_points(f).view(b, n, 2, h * pq * 3)
        q_pts = to_world(qk_pts[:, :, 0], pq).view(b, n, h, pq * 3)
        k_pts = to_world(qk_pts[:, :, 1], pq).view(b, n, h, pq * 3)
        v_pts = to_world(self.to_v_points(f), pv).view(b, n, h, pv * 3)

        # Squared point distances, summed over the points of a head; the direct difference keeps
        # float32 invariance tight where |x|^2 + |y|^2 - 2 x.y would cancel.
        gamma = F.softplus(self.point_weight) * self.w_c / 2  # (H,)
        diff = q_pts[:, :, None] - k_pts[:, None, :]  # (B, L, L, H, 3 N_qp)
        point_logits = (diff * diff).sum(-1).permute(0, 3, 1, 2)  # (B, H, L, L)
        logits = self.w_l * torch.einsum("bihd,bjhd->bhij", q, k) - gamma[:, None, None] * point_logits
        if mask is not None:
            logits = logits.masked_fill(~(mask if mask.ndim == 3 else mask[None])[:, None], float("-inf"))
        attn = logits.softmax(-1)  # (B, H, L, L)

        o = torch.einsum("bhij,bjhd->bihd", attn, v).reshape(b, n, h * c)
        o_pts_world = torch.einsum("bhij,bjhd->bihd", attn, v_pts).reshape(b, n, h * pv, 3)
        # T_i^{-1} y = R_i^T (y - p_i)
        o_pts = torch.einsum("blji,blmj->blmi", r, o_pts_world - p[:, :, None, :])
        o_norm = torch.sqrt((o_pts * o_pts).sum(-1) + 1e-8)
        out = torch.cat((o, o_pts.reshape(b, n, h * pv * 3), o_norm), -1)
        return self.to_out(out)
