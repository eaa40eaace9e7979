"""Velocity-field backbones of ``euclidean_flow``, one interface for both:

    backbone(x (B, H, A), t (B,), cond (B, S, D)) -> v (B, H, A),   t = flow time in [0, 1].

- ``transformer``: :class:`lerobot_actionflow.nn.dp_transformer.DPTransformer` (observation
  steps are memory tokens).
- ``unet``: LeRobot's own ``DiffusionConditionalUnet1d``, imported (not copied), so that the
  comparison with LeRobot's ``diffusion`` policy is the same network trained with another
  objective. It takes the ``S`` observation features flattened to one FiLM vector
  ``(B, S * D)``, and a timestep that it embeds with ``DiffusionSinusoidalPosEmb``:
  ``[sin(x w_k), cos(x w_k)]``, ``w_k = 10^{-4 k / (d/2 - 1)}``, computed in floating point, so
  a real-valued timestep is accepted as is. Diffusion feeds integer steps in
  ``[0, num_train_timesteps) = [0, 100)``; here ``x = time_embed_scale * t`` (``[0, 1000]`` by
  default, the convention of rectified-flow image models), which spans the same frequencies.
"""

from __future__ import annotations

import torch
from lerobot.policies.diffusion.modeling_diffusion import DiffusionConditionalUnet1d
from torch import nn

from lerobot_actionflow.nn.dp_transformer import DPTransformer
from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig


class FlowUnet1d(nn.Module):
    """LeRobot's ``DiffusionConditionalUnet1d`` as a velocity field ``v(x, t, cond)``."""

    def __init__(self, config: EuclideanFlowConfig, cond_dim: int):
        super().__init__()
        # The UNet reads its sizes from the config by attribute (action_feature, down_dims,
        # kernel_size, n_groups, diffusion_step_embed_dim, use_film_scale_modulation,
        # gradient_checkpointing): EuclideanFlowConfig carries the same fields.
        self.unet = DiffusionConditionalUnet1d(config, global_cond_dim=cond_dim * config.n_obs_steps)
        self.time_scale = float(config.time_embed_scale)

    def forward(self, x: torch.Tensor, t: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """``x (B, H, A)``, ``t (B,)``, ``cond (B, S, D)`` -> ``(B, H, A)``."""
        return self.unet(x, self.time_scale * t, global_cond=cond.flatten(start_dim=1))


def make_backbone(config: EuclideanFlowConfig, cond_dim: int) -> nn.Module:
    """The velocity network named by ``config.backbone``."""
    action_dim = config.action_feature.shape[0]
    if config.backbone == "transformer":
        return DPTransformer(
            action_dim=action_dim,
            cond_dim=cond_dim,
            horizon=config.horizon,
            n_obs_steps=config.n_obs_steps,
            n_layer=config.n_layer,
            n_head=config.n_head,
            n_emb=config.n_emb,
            p_drop_emb=config.p_drop_emb,
            p_drop_attn=config.p_drop_attn,
            causal_attn=config.causal_attn,
            time_scale=config.time_embed_scale,
        )
    if config.backbone == "unet":
        return FlowUnet1d(config, cond_dim)
    raise ValueError(f"unknown backbone {config.backbone!r}: expected 'transformer' or 'unet'")
