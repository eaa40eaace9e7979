"""SE(3)-invariant transformer: a stack of IPA blocks conditioned on flow time.

Block (post-LayerNorm, as in AlphaFold2's structure module)::

    f <- f + Linear_l(c)                          # time conditioning, c = emb(t)  (B, C)
    f <- LayerNorm(f + Dropout(IPA(f, T)))
    f <- LayerNorm(f + Dropout(MLP(f)))

The frames ``T`` are inputs only (not updated), so every block, and the stack, is invariant
to a global SE(3) transform of all frames.
"""

from __future__ import annotations

import torch
from torch import nn

from lerobot_actionflow.nn.ipa import InvariantPointAttention


class IPABlock(nn.Module):
    def __init__(
        self,
        dim: int,
        num_heads: int,
        head_dim: int,
        num_query_points: int,
        num_value_points: int,
        mlp_ratio: float = 2.0,
        dropout: float = 0.0,
    ):
        super().__init__()
        self.cond = nn.Linear(dim, dim)
        self.ipa = InvariantPointAttention(dim, num_heads, head_dim, num_query_points, num_value_points)
        self.norm1 = nn.LayerNorm(dim)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim))
        self.norm2 = nn.LayerNorm(dim)
        self.drop = nn.Dropout(dropout)

    def forward(
        self,
        f: torch.Tensor,
        r: torch.Tensor,
        p: torch.Tensor,
        cond: torch.Tensor,
        mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``f (B, L, C)``, ``r (B, L, 3, 3)``, ``p (B, L, 3)``, ``cond (B, C)`` -> ``(B, L, C)``."""
        f = f + self.cond(cond)[:, None]
        f = self.norm1(f + self.drop(self.ipa(f, r, p, mask)))
        return self.norm2(f + self.drop(self.mlp(f)))


class SE3InvariantTransformer(nn.Module):
    """``depth`` IPA blocks sharing the same frames."""

    def __init__(
        self,
        dim: int = 128,
        depth: int = 4,
        num_heads: int = 8,
        head_dim: int = 16,
        num_query_points: int = 4,
        num_value_points: int = 8,
        mlp_ratio: float = 2.0,
        dropout: float = 0.0,
    ):
        super().__init__()
        self.blocks = nn.ModuleList(
            IPABlock(dim, num_heads, head_dim, num_query_points, num_value_points, mlp_ratio, dropout)
            for _ in range(depth)
        )

    def forward(self, f, r, p, cond, mask=None):
        for block in self.blocks:
            f = block(f, r, p, cond, mask)
        return f
