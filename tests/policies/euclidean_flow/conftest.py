"""Shared helpers for the ``euclidean_flow`` tests: a tiny LeRobotDataset in the project's schema
(:mod:`tests.synthetic_dataset`) and a policy trained on a two-mode task."""

from __future__ import annotations

from pathlib import Path

import pytest

from ...synthetic_dataset import make_reach_dataset


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """Root of a tiny dataset (repo id ``local/euclidean_flow_tiny``), built once per session."""
    root = tmp_path_factory.mktemp("data") / "euclidean_flow_tiny"
    return make_reach_dataset(root, repo_id="local/euclidean_flow_tiny", episodes=2)


# ------------------------------------------------------------------------------------------------
# A policy trained on a two-mode task: for the same observation the action chunk is all +1 or
# all -1 (normalised units), each with probability 1/2.
BIMODAL_HORIZON, BIMODAL_OBS_DIM = 2, 3


def bimodal_config(**overrides):
    from lerobot.configs.types import FeatureType, PolicyFeature

    from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig

    kwargs = dict(
        device="cpu",
        n_layer=1,
        n_emb=32,
        p_drop_attn=0.0,
        n_obs_steps=1,
        horizon=BIMODAL_HORIZON,
        n_action_steps=BIMODAL_HORIZON,
        num_inference_steps=10,
        input_features={"observation.state": PolicyFeature(FeatureType.STATE, (BIMODAL_OBS_DIM,))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (1,))},
    )
    kwargs.update(overrides)
    return EuclideanFlowConfig(**kwargs)


def bimodal_batch(batch_size: int, generator) -> dict:
    import torch

    sign = torch.randint(0, 2, (batch_size, 1, 1), generator=generator).float() * 2 - 1
    return {
        "observation.state": torch.zeros(batch_size, 1, BIMODAL_OBS_DIM),
        "action": sign.expand(batch_size, BIMODAL_HORIZON, 1).clone(),
    }


@pytest.fixture(scope="session")
def bimodal_policy():
    """``EuclideanFlowPolicy`` (transformer) fitted to the two-mode task (a few seconds)."""
    import torch

    from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy

    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(0)
    policy = EuclideanFlowPolicy(bimodal_config())
    opt = torch.optim.Adam(policy.parameters(), lr=2e-3)
    policy.train()
    for _ in range(400):
        loss, _ = policy.forward(bimodal_batch(256, gen))
        opt.zero_grad()
        loss.backward()
        opt.step()
    policy.eval()
    return policy


@pytest.fixture(scope="session")
def bimodal_checkpoint(bimodal_policy, tmp_path_factory) -> Path:
    """``bimodal_policy`` saved like a lerobot-train checkpoint (weights, config, processors);
    the stats make min-max normalisation the identity on actions in [-1, 1]."""
    import torch
    from lerobot.policies.factory import make_pre_post_processors

    path = tmp_path_factory.mktemp("ckpt") / "pretrained_model"
    stats = {
        "observation.state": {"min": -torch.ones(BIMODAL_OBS_DIM), "max": torch.ones(BIMODAL_OBS_DIM)},
        "action": {"min": -torch.ones(1), "max": torch.ones(1)},
    }
    pre, post = make_pre_post_processors(bimodal_policy.config, dataset_stats=stats)
    bimodal_policy.save_pretrained(path)
    pre.save_pretrained(path)
    post.save_pretrained(path)
    return path
