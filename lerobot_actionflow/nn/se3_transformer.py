"""SE(3)-invariant transformer: a stack of IPA blocks conditioned on flow time.

Block (post-LayerNorm, as in AlphaFold2's structure module)::

    f <- f + Linear_l(c)                          # time conditioning, c = emb(t)  (B, C)
    f <- LayerNorm(f + Dropout(IPA(f, T)))
    f <- LayerNorm(f + Dropout(MLP(f)))

The frames ``T`` are inputs only (not updated), so every block, and the stack, is invariant
to a global SE(3) transform of all frames.

Context caching (what makes K sampling steps cheap): tokens that do not depend on flow time
(the observations) are run once through :meth:`SE3InvariantTransformer.encode_context`, attending
only among themselves; each block keeps their keys and values. The time-dependent tokens (the
action chunk) then run through :meth:`SE3InvariantTransformer.forward_with_context` at every
step, attending to the cached context and to each other. This is the full transformer with an
attention mask (context cannot see the queries) and time conditioning on the queries only.
"""

from __future__ import annotations

import torch
from torch import nn

from lerobot_actionflow.nn.ipa import DEFAULT_IPA_SIZE, InvariantPointAttention, IPASize


class IPABlock(nn.Module):
    """One block of the module docstring: IPA of ``size``, an MLP of ``mlp_ratio * dim`` hidden units."""

    def __init__(self, size: IPASize, mlp_ratio: float = 2.0, dropout: float = 0.0):
        super().__init__()
        dim = size.dim
        self.cond = nn.Linear(dim, dim)
        self.ipa = InvariantPointAttention(size)
        self.norm1 = nn.LayerNorm(dim)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim))
        self.norm2 = nn.LayerNorm(dim)
        self.drop = nn.Dropout(dropout)

    def _update(self, f: torch.Tensor, attended: torch.Tensor) -> torch.Tensor:
        f = self.norm1(f + self.drop(attended))
        return self.norm2(f + self.drop(self.mlp(f)))

    def forward(
        self,
        f: torch.Tensor,
        r: torch.Tensor,
        p: torch.Tensor,
        cond: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Self-attention block: ``f (B, L, C)``, ``r (B, L, 3, 3)``, ``p (B, L, 3)``, optional
        ``cond (B, C)`` added to every token -> ``(B, L, C)``."""
        if cond is not None:
            f = f + self.cond(cond)[:, None]
        return self._update(f, self.ipa(f, r, p, mask))

    def context(
        self, f: torch.Tensor, r: torch.Tensor, p: torch.Tensor
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """Context tokens among themselves (no conditioning): updated features and the keys and
        values (of the block's input) that queries will attend to."""
        query, key, value = self.ipa.project(f, r, p)
        return self._update(f, self.ipa.attend(query, key, value, r, p)), (key, value)

    def forward_with_context(
        self,
        f: torch.Tensor,
        r: torch.Tensor,
        p: torch.Tensor,
        shift: torch.Tensor,
        context: tuple[torch.Tensor, torch.Tensor],
    ) -> torch.Tensor:
        """Query tokens ``f (B, L, C)`` attend to the cached ``context`` and to themselves;
        ``shift = self.cond(c)`` ``(B or 1, C)`` is the block's time conditioning."""
        f = f + shift[:, None]
        query, key, value = self.ipa.project(f, r, p)
        key = torch.cat((context[0], key), 2)
        value = torch.cat((context[1], value), 2)
        return self._update(f, self.ipa.attend(query, key, value, r, p))


class SE3InvariantTransformer(nn.Module):
    """``depth`` IPA blocks sharing the same frames."""

    def __init__(
        self, size: IPASize = DEFAULT_IPA_SIZE, depth: int = 4, mlp_ratio: float = 2.0, dropout: float = 0.0
    ):
        super().__init__()
        self.blocks = nn.ModuleList(IPABlock(size, mlp_ratio, dropout) for _ in range(depth))

    def forward(self, f, r, p, cond=None, mask=None):
        """All tokens attend to each other (``mask`` optional): ``(B, L, C) -> (B, L, C)``."""
        for block in self.blocks:
            f = block(f, r, p, cond, mask)
        return f

    def encode_context(
        self, f: torch.Tensor, r: torch.Tensor, p: torch.Tensor
    ) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per-block keys/values of time-independent context tokens ``(B, M, C)``."""
        cache = []
        for block in self.blocks:
            f, kv = block.context(f, r, p)
            cache.append(kv)
        return cache

    def time_shifts(self, cond: torch.Tensor) -> list[torch.Tensor]:
        """Each block's conditioning ``Linear_l(c)`` for conditions ``c (N, C)``: ``depth x (N, C)``.

        The sampler knows every flow time of a chunk in advance, so it computes the shifts of all
        K steps at once (one matmul per block per chunk, not per step).
        """
        return [block.cond(cond) for block in self.blocks]

    def forward_with_context(
        self,
        f: torch.Tensor,
        r: torch.Tensor,
        p: torch.Tensor,
        cond: torch.Tensor | None,
        context: list[tuple[torch.Tensor, torch.Tensor]],
        shifts: list[torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Query tokens ``(B, L, C)`` through every block, attending to ``context``; the time
        conditioning is ``cond (B, C)`` or its precomputed ``shifts`` (:meth:`time_shifts`)."""
        if shifts is None:
            shifts = self.time_shifts(cond)
        for block, kv, shift in zip(self.blocks, context, shifts, strict=True):
            f = block.forward_with_context(f, r, p, shift, kv)
        return f
