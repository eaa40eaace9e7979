"""Config validation of the few-step options (training-time law, solver, shortcut objective)."""

import pytest

from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig
from lerobot_actionflow.policies.config_errors import PolicyConfigError
from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig

BOTH = (ActionflowConfig, EuclideanFlowConfig)

REFUSED = [
    ({"train_time_distribution": "lognormal"}, r"`train_time_distribution` must be one of"),
    ({"train_time_logit_normal": (0.0, 0.0)}, r"`train_time_logit_normal` must be \(mean, std\)"),
    ({"train_time_logit_normal": (float("nan"), 1.0)}, r"`train_time_logit_normal`"),
    ({"train_time_logit_normal": (0.0,)}, r"`train_time_logit_normal`"),
]


@pytest.mark.parametrize("cls", BOTH)
@pytest.mark.parametrize(("overrides", "message"), REFUSED)
def test_bad_training_time_options_are_refused(cls, overrides, message):
    with pytest.raises(PolicyConfigError, match=message):
        cls(device="cpu", **overrides)


@pytest.mark.parametrize("cls", BOTH)
def test_logit_normal_training_times_are_accepted(cls):
    cfg = cls(device="cpu", train_time_distribution="logit_normal", train_time_logit_normal=(0.5, 0.8))
    assert cfg.train_time_logit_normal == (0.5, 0.8)
