"""Small ActionFlow configs and synthetic pose batches for the tests."""

from __future__ import annotations

import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow import geometry as g
from lerobot_actionflow.geometry.se3 import rp_to_pose7
from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig
from lerobot_actionflow.schema.tensors import action_to_pose, pose_to_action


def small_config(
    num_entities=4, n_obs_steps=2, horizon=8, with_state=True, images=(), **kw
) -> ActionflowConfig:
    inputs = {"observation.poses": PolicyFeature(FeatureType.STATE, (num_entities, 7))}
    if with_state:
        inputs["observation.state"] = PolicyFeature(FeatureType.STATE, (11,))
    for cam in images:
        inputs[f"observation.images.{cam}"] = PolicyFeature(FeatureType.VISUAL, (3, 32, 32))
    defaults = dict(
        dim=32, num_layers=2, num_heads=2, head_dim=8, num_query_points=2, num_value_points=2,
        n_action_steps=4, device="cpu", image_size=(32, 32),
    )  # fmt: skip
    defaults.update(kw)
    return ActionflowConfig(
        n_obs_steps=n_obs_steps,
        horizon=horizon,
        input_features=inputs,
        output_features={"action": PolicyFeature(FeatureType.ACTION, (10,))},
        **defaults,
    )


def random_batch(cfg: ActionflowConfig, batch_size: int, gen: torch.Generator, dtype=torch.float32) -> dict:
    """Observations with entities scattered around a random EEF, and actions near them."""
    n = cfg.input_features["observation.poses"].shape[0]
    h_o, h = cfg.n_obs_steps, cfg.horizon
    r = g.random_rotation(batch_size, h_o, n, generator=gen, dtype=dtype)
    p = 0.3 * torch.randn(batch_size, h_o, n, 3, generator=gen, dtype=dtype)
    batch = {"observation.poses": rp_to_pose7(r, p)}
    if "observation.state" in cfg.input_features:
        batch["observation.state"] = torch.randn(batch_size, h_o, 11, generator=gen, dtype=dtype)
    for key, ft in cfg.image_features.items():
        batch[key] = torch.rand(batch_size, h_o, *ft.shape, generator=gen, dtype=dtype)
    ra = g.random_rotation(batch_size, h, generator=gen, dtype=dtype)
    pa = 0.2 * torch.randn(batch_size, h, 3, generator=gen, dtype=dtype)
    ga = torch.rand(batch_size, h, generator=gen, dtype=dtype) * 2 - 1
    batch["action"] = pose_to_action(ra, pa, ga)
    return batch


def transform_batch(batch: dict, r_d: torch.Tensor, p_d: torch.Tensor) -> dict:
    """Apply the rigid transform (r_d, p_d) to every pose in the batch (observations and actions)."""
    out = dict(batch)
    r, p = g.se3.pose7_to_rp(batch["observation.poses"])
    out["observation.poses"] = rp_to_pose7(r_d @ r, (r_d @ p[..., None]).squeeze(-1) + p_d)
    if "action" in batch:
        ra, pa, ga = action_to_pose(batch["action"])
        out["action"] = pose_to_action(r_d @ ra, (r_d @ pa[..., None]).squeeze(-1) + p_d, ga)
    return out
