"""Bad input is refused with a message that names the feature and the expected shape."""

import pytest
import torch
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature

from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy

from .helpers import random_batch, small_config


@pytest.fixture(scope="module")
def policy():
    torch.manual_seed(0)
    return ActionflowPolicy(small_config()).eval()


@pytest.fixture
def batch(policy):
    return random_batch(policy.config, 2, torch.Generator().manual_seed(0))


def test_missing_feature_is_named(policy, batch):
    del batch["observation.poses"]
    with pytest.raises(ValueError, match=r"missing input feature 'observation\.poses'"):
        policy.predict_action_chunk(batch)
    with pytest.raises(ValueError, match=r"missing input feature 'action'"):
        policy.forward(
            {k: v for k, v in random_batch(policy.config, 2, torch.Generator()).items() if k != "action"}
        )


def test_wrong_shapes_name_the_expected_shape(policy, batch):
    with pytest.raises(
        ValueError, match=r"'observation\.poses' has shape \(2, 2, 3, 7\).*, expected \(B, 2, 4, 7\)"
    ):
        policy.predict_action_chunk({**batch, "observation.poses": batch["observation.poses"][:, :, :3]})
    with pytest.raises(ValueError, match=r"'action' must have shape \(B, 8, 10\)"):
        policy.forward({**batch, "action": batch["action"][..., :9]})
    with pytest.raises(ValueError, match=r"'observation\.state' has shape \(2, 11\).*expected \(B, 2, 11\)"):
        policy.predict_action_chunk({**batch, "observation.state": batch["observation.state"][:, 0]})


def test_non_finite_inputs_are_refused(policy, batch):
    poses = batch["observation.poses"].clone()
    poses[1, 0, 2, 0] = float("nan")
    with pytest.raises(ValueError, match=r"observation\.poses\[1, 0, 2\] is not finite"):
        policy.predict_action_chunk({**batch, "observation.poses": poses})
    action = batch["action"].clone()
    action[0, 3, 9] = float("inf")
    with pytest.raises(ValueError, match=r"action\[0, 3\] is not finite"):
        policy.forward({**batch, "action": action})


def test_quaternions_off_the_manifold_are_refused_and_drift_is_projected(policy, batch):
    poses = batch["observation.poses"].clone()
    poses[0, 1, 1, 3:] *= 1.5
    with pytest.raises(ValueError, match=r"observation\.poses\[0, 1, 1\] is not a unit quaternion"):
        policy.predict_action_chunk({**batch, "observation.poses": poses})
    drift = batch["observation.poses"].clone()
    drift[..., 3:] *= 1.001
    torch.manual_seed(0)
    a = policy.predict_action_chunk(batch)
    torch.manual_seed(0)
    b = policy.predict_action_chunk({**batch, "observation.poses": drift})
    assert torch.allclose(a, b, atol=1e-5)


def test_config_refuses_unusable_features():
    with pytest.raises(ValueError, match=r"needs the input feature 'observation\.poses'"):
        ActionflowPolicy(small_config(with_state=True).__class__(
            input_features={"observation.state": PolicyFeature(FeatureType.STATE, (11,))},
            output_features={"action": PolicyFeature(FeatureType.ACTION, (10,))}, device="cpu",
        ))  # fmt: skip
    cfg = small_config()
    cfg.output_features = {"action": PolicyFeature(FeatureType.ACTION, (7,))}
    with pytest.raises(ValueError, match=r"'action' must have shape \(10,\)"):
        cfg.validate_features()
    with pytest.raises(ValueError, match="must be IDENTITY"):
        small_config(normalization_mapping={"STATE": NormalizationMode.MEAN_STD})
    with pytest.raises(ValueError, match="n_action_steps"):
        small_config(n_action_steps=9)
