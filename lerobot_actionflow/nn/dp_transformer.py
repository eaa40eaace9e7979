"""Diffusion-Policy-style transformer for a velocity (or denoising) field over an action chunk.

The network of Diffusion Policy's transformer variant (Chi et al. 2023), written here from its
description: a decoder-only stack in which the ``H`` action tokens attend to each other with a
causal mask and, through cross-attention, to a short memory of conditioning tokens
``[time, obs_0, ..., obs_{n_obs-1}]``.

Shapes (``B`` batch, ``H`` horizon, ``A`` action size, ``S = n_obs_steps``, ``D`` obs feature
size, ``E = n_emb``)::

    x    (B, H, A)  current point on the path a_t (or a noisy chunk)
    t    (B,)       flow time in [0, 1] (any float; scaled by ``time_scale`` before embedding)
    cond (B, S, D)  one feature vector per observation step
    out  (B, H, A)  predicted velocity v(a_t, t, o)

Time embedding: ``e(t) = [sin(s t w_k), cos(s t w_k)]_k`` with ``w_k = 10^{-4 k / (E/2 - 1)}``,
``k = 0..E/2-1`` and ``s = time_scale`` (1000 by default, so that flow time spans the range of
integer diffusion steps).

Masks: action token ``i`` may attend action tokens ``j <= i`` (causal self-attention) and the
memory tokens "time" and ``obs_j`` with ``j <= i`` (an action never sees a later observation;
the action at index ``i`` is aligned with observation step ``i``, as in LeRobot's chunks that
start at the oldest observation).

No LeRobot imports.
"""

from __future__ import annotations

import math

import torch
from torch import nn


def sinusoidal_embedding(x: torch.Tensor, dim: int) -> torch.Tensor:
    """``(B,)`` -> ``(B, dim)``: ``[sin(x w_k), cos(x w_k)]`` with ``w_k = 10^{-4 k/(dim/2 - 1)}``."""
    if dim % 2 or dim < 4:
        raise ValueError(f"sinusoidal embedding size must be even and >= 4, got {dim}")
    half = dim // 2
    freqs = torch.exp(-math.log(1e4) * torch.arange(half, device=x.device, dtype=torch.float32) / (half - 1))
    arg = x.float()[:, None] * freqs[None]
    return torch.cat((arg.sin(), arg.cos()), dim=-1)


class DPTransformer(nn.Module):
    """Velocity field ``v(x, t, cond)`` with Diffusion Policy's transformer layout.

    Args:
        action_dim: ``A``.
        cond_dim: ``D``, size of one observation-step feature.
        horizon: ``H``, number of action tokens.
        n_obs_steps: ``S``, number of observation tokens.
        n_layer, n_head, n_emb: decoder depth, heads and width (Diffusion Policy: 8, 4, 256).
        p_drop_emb: dropout on the token embeddings.
        p_drop_attn: dropout inside the attention and feed-forward blocks.
        causal_attn: causal self-attention over actions and step-aligned cross-attention
            (see module docstring); ``False`` lets every token see everything.
        time_scale: ``s`` in the time embedding.
    """

    def __init__(
        self,
        action_dim: int,
        cond_dim: int,
        horizon: int,
        n_obs_steps: int,
        n_layer: int = 8,
        n_head: int = 4,
        n_emb: int = 256,
        p_drop_emb: float = 0.0,
        p_drop_attn: float = 0.1,
        causal_attn: bool = True,
        time_scale: float = 1000.0,
    ):
        super().__init__()
        if n_emb % n_head:
            raise ValueError(f"n_emb ({n_emb}) must be divisible by n_head ({n_head})")
        self.horizon, self.n_obs_steps, self.n_emb = horizon, n_obs_steps, n_emb
        self.time_scale = float(time_scale)

        self.action_emb = nn.Linear(action_dim, n_emb)
        self.action_pos = nn.Parameter(torch.zeros(1, horizon, n_emb))
        self.cond_emb = nn.Linear(cond_dim, n_emb)
        self.cond_pos = nn.Parameter(torch.zeros(1, 1 + n_obs_steps, n_emb))
        self.drop = nn.Dropout(p_drop_emb)
        # Diffusion Policy's default with no condition encoder layers: a position-wise MLP.
        self.memory_mlp = nn.Sequential(nn.Linear(n_emb, 4 * n_emb), nn.Mish(), nn.Linear(4 * n_emb, n_emb))
        layer = nn.TransformerDecoderLayer(
            d_model=n_emb,
            nhead=n_head,
            dim_feedforward=4 * n_emb,
            dropout=p_drop_attn,
            activation="gelu",
            batch_first=True,
            norm_first=True,
        )
        self.decoder = nn.TransformerDecoder(layer, num_layers=n_layer)
        self.norm = nn.LayerNorm(n_emb)
        self.head = nn.Linear(n_emb, action_dim)

        if causal_attn:
            i = torch.arange(horizon)[:, None]
            self_mask = torch.arange(horizon)[None, :] > i  # True = blocked
            obs_step = torch.arange(1 + n_obs_steps)[None, :] - 1  # memory index -> obs step (time: -1)
            memory_mask = obs_step > i
        else:
            self_mask = torch.zeros(horizon, horizon, dtype=torch.bool)
            memory_mask = torch.zeros(horizon, 1 + n_obs_steps, dtype=torch.bool)
        self.causal_attn = causal_attn
        self.register_buffer("self_mask", self_mask, persistent=False)
        self.register_buffer("memory_mask", memory_mask, persistent=False)
        self.apply(self._init_weights)
        nn.init.normal_(self.action_pos, std=0.02)
        nn.init.normal_(self.cond_pos, std=0.02)

    @staticmethod
    def _init_weights(module: nn.Module) -> None:
        if isinstance(module, nn.Linear):
            nn.init.normal_(module.weight, std=0.02)
            if module.bias is not None:
                nn.init.zeros_(module.bias)

    def forward(self, x: torch.Tensor, t: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """``x (B, H, A)``, ``t (B,)``, ``cond (B, S, D)`` -> ``(B, H, A)``."""
        if x.shape[1] != self.horizon or cond.shape[1] != self.n_obs_steps:
            raise ValueError(
                f"expected x (B, {self.horizon}, A) and cond (B, {self.n_obs_steps}, D), "
                f"got {tuple(x.shape)} and {tuple(cond.shape)}"
            )
        time_tok = sinusoidal_embedding(self.time_scale * t, self.n_emb).to(x.dtype)[:, None]  # (B, 1, E)
        memory = torch.cat((time_tok, self.cond_emb(cond)), dim=1) + self.cond_pos  # (B, 1+S, E)
        memory = self.memory_mlp(self.drop(memory))
        tokens = self.drop(self.action_emb(x) + self.action_pos)  # (B, H, E)
        # tgt_is_causal states what the mask is, rather than have torch compare it with a causal
        # mask at every call (a data-dependent check that torch.export cannot trace).
        h = self.decoder(
            tokens,
            memory,
            tgt_mask=self.self_mask,
            memory_mask=self.memory_mask,
            tgt_is_causal=self.causal_attn,
        )
        return self.head(self.norm(h))
