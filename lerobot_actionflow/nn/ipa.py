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
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn


@dataclass(frozen=True)
class IPASize:
    """The sizes of an IPA layer.

    Attributes:
        dim: feature size ``C``.
        num_heads: ``N_head``.
        head_dim: scalar channels per head ``c``.
        num_query_points: ``N_qp`` query/key points per head.
        num_value_points: ``N_pv`` value points per head.
    """

    dim: int = 128
    num_heads: int = 8
    head_dim: int = 16
    num_query_points: int = 4
    num_value_points: int = 8


#: The paper's IPA sizes (App. D).
DEFAULT_IPA_SIZE = IPASize()


class InvariantPointAttention(nn.Module):
    """IPA over a set of posed tokens of the given :class:`IPASize`."""

    def __init__(self, size: IPASize):
        super().__init__()
        dim, num_heads, head_dim = size.dim, size.num_heads, size.head_dim
        num_query_points, num_value_points = size.num_query_points, size.num_value_points
        self.num_heads, self.head_dim = num_heads, head_dim
        self.num_query_points, self.num_value_points = num_query_points, num_value_points
        # One projection for everything: scalar q, k, v (3 H c) and the local points q, k (2 H N_qp 3)
        # and v (H N_pv 3); a single matmul is what matters at batch 1.
        self._split = (3 * num_heads * head_dim, num_heads * (2 * num_query_points + num_value_points) * 3)
        self.to_inputs = nn.Linear(dim, sum(self._split))
        # softplus(0.5413) = 1: every head starts with unit point weight.
        self.point_weight = nn.Parameter(torch.full((num_heads,), math.log(math.e - 1)))
        self.w_l = 1.0 / math.sqrt(3 * head_dim)
        self.w_c = math.sqrt(2.0 / (9 * num_query_points))
        self.to_out = nn.Linear(num_heads * (head_dim + num_value_points * 4), dim)

    def project(
        self, f: torch.Tensor, r: torch.Tensor, p: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Fused queries, keys and values of tokens ``f (B, L, C)`` with frames ``r, p``.

        The point term is folded into one dot product:
        ``-g |x_i - y_j|^2 = 2 g x_i.y_j - g |y_j|^2 - g |x_i|^2``, and the last term is constant
        over ``j``, so it cancels in the softmax. Queries ``[w_L q, 2 g q^p, 1]`` against keys
        ``[k, k^p, -g |k^p|^2]`` give exactly the logits of the module docstring, and values
        ``[v, T_j v^p]`` give both outputs at once.

        Returns:
            query ``(B, H, L, c + 3 N_qp + 1)``, key (same), value ``(B, H, L, c + 3 N_pv)``.
        """
        b, n, _ = f.shape
        h, c, pq, pv = self.num_heads, self.head_dim, self.num_query_points, self.num_value_points
        scalars, points = self.to_inputs(f).split(self._split, -1)
        q, k, v = scalars.view(b, n, 3, h, c).unbind(2)  # (B, L, H, c)
        # World frame, T_i x = R_i x + p_i, as row vectors x R_i^T: one batched (M, 3) @ (3, 3) per
        # token, cheaper than an einsum that permutes and copies its operands first.
        pts = points.view(b, n, h * (2 * pq + pv), 3) @ r.transpose(-1, -2) + p[:, :, None, :]
        q_pts, k_pts, v_pts = pts.view(b, n, h, (2 * pq + pv) * 3).split((pq * 3, pq * 3, pv * 3), -1)
        gamma = (F.softplus(self.point_weight) * (self.w_c / 2))[:, None]  # (H, 1)
        query = torch.cat((self.w_l * q, 2 * gamma * q_pts, torch.ones_like(q[..., :1])), -1)
        key = torch.cat((k, k_pts, -gamma * (k_pts * k_pts).sum(-1, keepdim=True)), -1)
        value = torch.cat((v, v_pts), -1)
        return query.transpose(1, 2), key.transpose(1, 2), value.transpose(1, 2)

    def attend(
        self,
        query: torch.Tensor,
        key: torch.Tensor,
        value: torch.Tensor,
        r: torch.Tensor,
        p: torch.Tensor,
        mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Attention of the query tokens (frames ``r (B, L, 3, 3)``, ``p (B, L, 3)``) over any set
        of keys/values from :meth:`project`; returns the ``(B, L, C)`` invariant update.

        ``mask``: optional boolean ``(B, L, M)`` or ``(L, M)``, True where query i may attend key j.
        """
        b, _, n, _ = query.shape
        h, c, pv = self.num_heads, self.head_dim, self.num_value_points
        logits = query @ key.transpose(-1, -2)  # (B, H, L, M)
        if mask is not None:
            logits = logits.masked_fill(~(mask if mask.ndim == 3 else mask[None])[:, None], float("-inf"))
        # A plain softmax-matmul: at these sizes it beats scaled_dot_product_attention's CPU path.
        out = (logits.softmax(-1) @ value).transpose(1, 2)  # (B, L, H, c + 3 N_pv)
        o, o_pts = out.split((c, pv * 3), -1)
        # Back into token i's frame: T_i^{-1} y = R_i^T (y - p_i).
        o_pts = (o_pts.reshape(b, n, h * pv, 3) - p[:, :, None, :]) @ r  # rows (y - p_i)^T R_i
        o_norm = torch.sqrt((o_pts * o_pts).sum(-1) + 1e-8)
        return self.to_out(torch.cat((o.reshape(b, n, h * c), o_pts.reshape(b, n, h * pv * 3), o_norm), -1))

    def forward(
        self, f: torch.Tensor, r: torch.Tensor, p: torch.Tensor, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Self-attention among the tokens ``f (B, L, C)``, frames ``r (B, L, 3, 3)``,
        ``p (B, L, 3)``; returns ``(B, L, C)`` invariant updates.

        Positions enter through ``|k^p|^2``: callers keep them near the origin (the network
        re-expresses poses in the EEF frame, or centres them) so that float32 stays exact.
        """
        query, key, value = self.project(f, r, p)
        return self.attend(query, key, value, r, p, mask)
