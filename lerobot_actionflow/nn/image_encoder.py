"""ResNet18 image features for camera tokens (App. G: 80x80 images).

Weights start random (nothing is downloaded); ``weights_path`` may name a local torchvision
ResNet18 state dict (e.g. ImageNet weights saved with ``torch.save(model.state_dict(), f)``).
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
import torchvision
from torch import nn


class ResNet18Encoder(nn.Module):
    """``(B, 3, H, W)`` images -> ``(B, 512)`` globally pooled features, resized to ``size``."""

    out_dim = 512

    def __init__(self, size: tuple[int, int] | None = (80, 80), weights_path: str | Path | None = None):
        super().__init__()
        net = torchvision.models.resnet18(weights=None)
        if weights_path is not None:
            path = Path(weights_path)
            if not path.is_file():
                raise FileNotFoundError(f"ResNet18 weights file not found: {path}")
            state = torch.load(path, map_location="cpu", weights_only=True)
            missing, unexpected = net.load_state_dict(state, strict=False)
            if [k for k in missing if not k.startswith("fc.")] or unexpected:
                raise ValueError(
                    f"{path} is not a torchvision ResNet18 state dict (missing {missing[:3]}...)"
                )
        net.fc = nn.Identity()
        self.net = net
        self.size = tuple(size) if size is not None else None

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        if self.size is not None and tuple(images.shape[-2:]) != self.size:
            images = F.interpolate(
                images, size=self.size, mode="bilinear", align_corners=False, antialias=True
            )
        return self.net(images)
