"""A checkpoint whose weights do not match the config is refused, naming what differs."""

import dataclasses

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig
from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy

from .actionflow.helpers import small_config


def _euclidean_config(**kw):
    return EuclideanFlowConfig(
        device="cpu", n_layer=2, n_emb=32, horizon=8, n_action_steps=4,
        input_features={"observation.state": PolicyFeature(FeatureType.STATE, (11,))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (10,))}, **kw,
    )  # fmt: skip


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    """A 2-layer checkpoint of each policy, saved by LeRobot's ``save_pretrained``."""
    torch.manual_seed(0)
    root = tmp_path_factory.mktemp("ckpt")
    ActionflowPolicy(small_config(num_layers=2)).save_pretrained(root / "actionflow")
    EuclideanFlowPolicy(_euclidean_config()).save_pretrained(root / "euclidean_flow")
    return root


MISSING = r"missing from the checkpoint \(\d+\):\n    "
UNEXPECTED = r"in the checkpoint but not in the model \(\d+\):\n    "
SHAPE = r"of a different shape \(\d+\):\n    "
CASES = [
    # policy, checkpoint, config change, what the error must list
    (ActionflowPolicy, "actionflow", {"num_layers": 3}, MISSING + r"network\.transformer\.blocks\.2\."),
    (ActionflowPolicy, "actionflow", {"num_layers": 1}, UNEXPECTED + r"network\.transformer\.blocks\.1\."),
    (ActionflowPolicy, "actionflow", {"dim": 48}, SHAPE + r"\S+: checkpoint \(.*32.*\), model \(.*48.*\)"),
    (EuclideanFlowPolicy, "euclidean_flow", {"n_layer": 3}, MISSING),
    (EuclideanFlowPolicy, "euclidean_flow", {"n_emb": 64}, SHAPE),
]


@pytest.mark.parametrize(("policy_cls", "name", "change", "message"), CASES)
def test_mismatched_checkpoint_is_refused(checkpoints, policy_cls, name, change, message):
    path = checkpoints / name
    saved = policy_cls.config_class.from_pretrained(path)
    config = dataclasses.replace(saved, **change)
    with pytest.raises(ValueError, match=message) as info:
        policy_cls.from_pretrained(path, config=config)
    assert "do not match" in str(info.value)
    # Controls: the checkpoint's own config loads; strict=False stays available on request
    # (torch refuses reshaped parameters even then).
    assert isinstance(policy_cls.from_pretrained(path, config=saved), policy_cls)
    if message != SHAPE and not message.startswith(SHAPE):
        policy_cls.from_pretrained(path, config=config, strict=False)
