"""The robot's flat layout round-trips to the dataset's features, through LeRobot's own
feature machinery and the policy-side processor step."""

import numpy as np
import pytest
import torch
from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.utils.feature_utils import hw_to_dataset_features

import lerobot_actionflow.envs  # noqa: F401
from lerobot_actionflow.envs.tasks import get_task
from lerobot_actionflow.robots.layout import (
    action_from_dict,
    action_names,
    flat_width,
    flatten_observation,
    observation_names,
    split_flat_observation,
)
from lerobot_actionflow.robots.processor import RobotObservationToPolicyStep
from lerobot_actionflow.schema import (
    ACTION_DIM,
    ENV_AGENT_POS,
    ENV_POSES,
    ENV_STATE,
    ENV_STATE_KEY,
    POSES_KEY,
    STATE_KEY,
    env_state_dim,
    feature_shapes,
)


def _random_env_obs(n: int, rng) -> dict:
    return {
        ENV_AGENT_POS: rng.normal(size=11).astype(np.float32),
        ENV_STATE: rng.normal(size=env_state_dim(n)).astype(np.float32),
        ENV_POSES: rng.normal(size=(n, 7)).astype(np.float32),
    }


@pytest.mark.parametrize("task", ["Lift", "StackThree_D0"])
def test_flat_observation_splits_back_into_the_dataset_features(task):
    spec = get_task(task)
    n = spec.num_tokens
    names = observation_names(spec)
    assert len(names) == flat_width(n) == 16 * n + 2
    env_obs = _random_env_obs(n, np.random.default_rng(0))
    flat = flatten_observation(env_obs, names)
    # LeRobot's rollout builds the robot's observation.state from the names, in this order.
    ds = hw_to_dataset_features(dict.fromkeys(names, float), "observation")
    vec = np.array([flat[k] for k in ds[STATE_KEY]["names"]], dtype=np.float32)
    out = RobotObservationToPolicyStep(num_tokens=n).observation({STATE_KEY: torch.from_numpy(vec)[None]})
    np.testing.assert_array_equal(out[STATE_KEY][0].numpy(), env_obs[ENV_AGENT_POS])
    np.testing.assert_array_equal(out[ENV_STATE_KEY][0].numpy(), env_obs[ENV_STATE])
    np.testing.assert_array_equal(out[POSES_KEY][0].numpy(), env_obs[ENV_POSES])


def test_step_declares_the_dataset_features_and_passes_dataset_batches_through():
    n = 3
    step = RobotObservationToPolicyStep(num_tokens=n)
    feats = {
        PipelineFeatureType.OBSERVATION: {STATE_KEY: PolicyFeature(FeatureType.STATE, (flat_width(n),))},
        PipelineFeatureType.ACTION: {},
    }
    obs = step.transform_features(feats)[PipelineFeatureType.OBSERVATION]
    assert {k: tuple(v.shape) for k, v in obs.items()} == {
        k: s for k, s in feature_shapes(n).items() if k != "action"
    }
    assert obs[ENV_STATE_KEY].type is FeatureType.ENV
    # Dataset batches (with or without pose tokens, with a time axis) pass untouched.
    for batch in (
        {POSES_KEY: torch.zeros(4, 2, n, 7), STATE_KEY: torch.ones(4, 2, 11)},
        {STATE_KEY: torch.ones(4, 2, 11), ENV_STATE_KEY: torch.ones(4, 2, env_state_dim(n))},
    ):
        out = step.observation(dict(batch))
        assert out.keys() == batch.keys() and all(out[k] is batch[k] for k in batch)
    with pytest.raises(ValueError, match=r"last dimension 50 .* got shape \(1, 12\)"):
        step.observation({STATE_KEY: torch.ones(1, 12)})


def test_action_dict_is_checked_key_by_key():
    names = action_names()
    assert len(names) == ACTION_DIM and all(k.endswith(".pos") for k in names)
    good = dict(zip(names, np.arange(ACTION_DIM, dtype=float), strict=True))
    np.testing.assert_array_equal(action_from_dict(good), np.arange(ACTION_DIM))
    with pytest.raises(ValueError, match=r"missing \['gripper.pos'\]"):
        action_from_dict({k: v for k, v in good.items() if k != "gripper.pos"})
    with pytest.raises(ValueError, match=r"unknown \['elbow.pos'\]"):
        action_from_dict({**good, "elbow.pos": 0.0})
    with pytest.raises(ValueError, match=r"'target\.z\.pos' is not finite"):
        action_from_dict({**good, "target.z.pos": float("nan")})
    with pytest.raises(ValueError, match=r"'target\.x\.pos' must be a number"):
        action_from_dict({**good, "target.x.pos": "left"})
    with pytest.raises(ValueError, match="dict of 10 floats"):
        action_from_dict(np.zeros(ACTION_DIM))


def test_split_works_on_numpy_too():
    flat = np.arange(flat_width(2), dtype=np.float32)
    parts = split_flat_observation(flat, 2)
    assert parts[POSES_KEY].shape == (2, 7) and parts[STATE_KEY].shape == (11,)
