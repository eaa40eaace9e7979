"""Adaptation module (App. F.2): poses re-expressed in a reference frame, translations scaled
and squashed before they enter the network.

For a reference frame ``T_e = (R_e, p_e)`` (the current end-effector) and a pose ``(R, p)``:

    R' = R_e^T R,    p' = squash(s R_e^T (p - p_e)),   squash = tanh or identity.

Relative poses are unchanged by a global transform of the scene, so any network on top of
them is invariant; ``s`` (default 10) enlarges distances in IPA's point attention and tanh
bounds far-away objects to (-1, 1). With ``frame="world"`` the poses are only scaled by ``s``
(a rigid motion of the scene stays a rigid motion), and invariance rests on IPA alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class PoseAdaptation:
    frame: str = "eef"  # "eef" or "world"
    translation_scale: float = 10.0
    squash: bool = True

    def __post_init__(self):
        if self.frame not in ("eef", "world"):
            raise ValueError(f"adaptation frame must be 'eef' or 'world', got {self.frame!r}")
        if self.squash and self.frame == "world":
            raise ValueError(
                "tanh squashing of world-frame translations would break equivariance: use frame='eef'"
            )
        if not self.translation_scale > 0:
            raise ValueError(f"translation_scale must be > 0, got {self.translation_scale}")

    def __call__(
        self, r_ref: torch.Tensor, p_ref: torch.Tensor, r: torch.Tensor, p: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Args: ``r_ref (B, 3, 3)``, ``p_ref (B, 3)``; ``r (B, L, 3, 3)``, ``p (B, L, 3)``.
        Returns the adapted ``(R', p')`` with the shapes of ``(r, p)``."""
        if self.frame == "world":
            return r, self.translation_scale * p
        rt = r_ref.transpose(-1, -2)[:, None]
        r_rel = rt @ r
        p_rel = (rt @ (p - p_ref[:, None])[..., None]).squeeze(-1) * self.translation_scale
        return r_rel, torch.tanh(p_rel) if self.squash else p_rel
