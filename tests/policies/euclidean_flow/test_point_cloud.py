"""``euclidean_flow`` with a PointNet global point-cloud encoder: it trains, samples, reads the
cloud, and refuses a missing one by name."""

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy
from lerobot_actionflow.policies.euclidean_flow.processor_euclidean_flow import (
    make_euclidean_flow_pre_post_processors,
)
from lerobot_actionflow.schema import POINT_CLOUD_KEY

from .conftest import bimodal_config

M = 32


def _config(**kw):
    feats = {
        "observation.state": PolicyFeature(FeatureType.STATE, (3,)),
        POINT_CLOUD_KEY: PolicyFeature(FeatureType.STATE, (M, 3)),
    }
    return bimodal_config(
        input_features=feats, point_cloud_key=POINT_CLOUD_KEY, point_cloud_width=16,
        point_cloud_feature_dim=8, n_obs_steps=2, horizon=4, n_action_steps=2, num_inference_steps=3, **kw,
    )  # fmt: skip


def _batch(gen, b=4):
    return {
        "observation.state": torch.randn(b, 2, 3, generator=gen),
        POINT_CLOUD_KEY: torch.randn(b, 2, M, 3, generator=gen).half(),
        "action": torch.rand(b, 4, 1, generator=gen) * 2 - 1,
    }


def test_trains_a_step_and_samples_from_point_clouds():
    torch.manual_seed(0)
    policy = EuclideanFlowPolicy(_config())
    gen = torch.Generator().manual_seed(1)
    batch = _batch(gen)
    loss, _ = policy.forward(batch)
    loss.backward()
    assert torch.isfinite(loss)
    assert any(p.grad.abs().sum() > 0 for p in policy.obs_encoder.point_encoder.parameters())
    policy.eval()
    noise = torch.randn(4, 4, 1, generator=gen)
    chunk = policy.predict_action_chunk(batch, noise=noise)
    assert chunk.shape == (4, 3, 1) and torch.isfinite(chunk).all()
    moved = {**batch, POINT_CLOUD_KEY: batch[POINT_CLOUD_KEY] + 0.5}
    assert not torch.equal(policy.predict_action_chunk(moved, noise=noise), chunk)  # the cloud is read
    policy.reset()
    step = {k: v[:, -1] for k, v in batch.items() if k != "action"}
    assert policy.select_action(step).shape == (4, 1)


def test_point_cloud_is_not_normalised():
    cfg = _config()
    stats = {
        "observation.state": {"min": torch.zeros(3), "max": torch.ones(3)},
        POINT_CLOUD_KEY: {"min": torch.full((M, 3), 5.0), "max": torch.full((M, 3), 6.0)},
        "action": {"min": -torch.ones(1), "max": torch.ones(1)},
    }
    pre, _ = make_euclidean_flow_pre_post_processors(cfg, stats)
    cloud = torch.randn(M, 3)
    out = pre({"observation.state": torch.ones(3), POINT_CLOUD_KEY: cloud})
    assert torch.equal(out[POINT_CLOUD_KEY].reshape(M, 3), cloud)
    assert torch.allclose(out["observation.state"], torch.ones(1, 3))  # min-max: 1 -> +1


def test_missing_cloud_feature_is_refused_by_name():
    with pytest.raises(ValueError, match=r"point_cloud_key is 'observation\.point_cloud'.*no such feature"):
        EuclideanFlowPolicy(bimodal_config(point_cloud_key=POINT_CLOUD_KEY))
    with pytest.raises(ValueError, match="point_cloud_width"):
        bimodal_config(point_cloud_width=0)


def test_environment_state_can_be_ignored():
    feats = {
        "observation.state": PolicyFeature(FeatureType.STATE, (3,)),
        "observation.environment_state": PolicyFeature(FeatureType.ENV, (9,)),
        POINT_CLOUD_KEY: PolicyFeature(FeatureType.STATE, (M, 3)),
    }
    cfg = bimodal_config(input_features=feats, point_cloud_key=POINT_CLOUD_KEY, use_environment_state=False)
    assert set(cfg.used_input_features) == {"observation.state", POINT_CLOUD_KEY}
    policy = EuclideanFlowPolicy(cfg)
    assert not policy.obs_encoder.use_env
    with_env = EuclideanFlowPolicy(bimodal_config(input_features=feats, point_cloud_key=POINT_CLOUD_KEY))
    assert with_env.obs_encoder.feature_dim == policy.obs_encoder.feature_dim + 9
