"""Sinusoidal embedding of flow time."""

from __future__ import annotations

import math

import torch
from torch import nn


class SinusoidalTimeEmbedding(nn.Module):
    """``t in [0, 1]`` ``(B,)`` -> ``(B, dim)``: ``[sin(s t w_k), cos(s t w_k)]`` with
    ``w_k = exp(-log(10^4) k / (dim/2))`` and ``s = 1000`` so that small time differences are
    resolved, followed by a 2-layer MLP."""

    def __init__(self, dim: int, scale: float = 1000.0):
        super().__init__()
        if dim % 2:
            raise ValueError(f"time embedding size must be even, got {dim}")
        half = dim // 2
        self.register_buffer("freqs", torch.exp(-math.log(1e4) * torch.arange(half) / half), persistent=False)
        self.scale = scale
        self.mlp = nn.Sequential(nn.Linear(dim, dim), nn.SiLU(), nn.Linear(dim, dim))

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        x = self.scale * t[:, None].to(self.freqs.dtype) * self.freqs
        return self.mlp(torch.cat((x.sin(), x.cos()), -1))
