"""A checkpoint ready for a robot gives, on the robot's flat observation, exactly the actions it
gives on the dataset's features. ActionFlow's and ``euclidean_flow``'s preprocessors carry the
splitting step from the start; a LeRobot ``diffusion`` checkpoint refuses the flat observation
until prepared (:func:`add_robot_observation_step`)."""

from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies import get_policy_class, make_pre_post_processors
from lerobot.policies.utils import prepare_observation_for_inference

import lerobot_actionflow.envs  # noqa: F401  (the task table)
from lerobot_actionflow.envs.tasks import get_task
from lerobot_actionflow.evaluation.untrained import save_untrained_actionflow
from lerobot_actionflow.robots.layout import flatten_observation, observation_names
from lerobot_actionflow.robots.processor import add_robot_observation_step
from lerobot_actionflow.schema import (
    ACTION_KEY,
    ENV_AGENT_POS,
    ENV_POSES,
    ENV_STATE,
    ENV_STATE_KEY,
    ENV_TO_DATASET_KEY,
    STATE_KEY,
    feature_shapes,
)

TASK = "Lift"


def _save_euclidean(kind: str, path: Path) -> Path:
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig

    shapes = feature_shapes(2)
    common = dict(
        input_features={
            STATE_KEY: PolicyFeature(FeatureType.STATE, shapes[STATE_KEY]),
            ENV_STATE_KEY: PolicyFeature(FeatureType.ENV, shapes[ENV_STATE_KEY]),
        },
        output_features={ACTION_KEY: PolicyFeature(FeatureType.ACTION, shapes[ACTION_KEY])},
        device="cpu", horizon=8, n_action_steps=4, num_inference_steps=2, push_to_hub=False,
    )  # fmt: skip
    if kind == "euclidean_flow":
        cfg = EuclideanFlowConfig(n_layer=1, n_emb=16, **common)
    else:
        cfg = DiffusionConfig(down_dims=(16, 32), **common)
    stats = {
        k: {"mean": torch.rand(s), "std": torch.rand(s) + 0.5, "min": -torch.ones(s), "max": torch.ones(s)}
        for k, s in shapes.items()
        if k in (STATE_KEY, ENV_STATE_KEY, ACTION_KEY)
    }
    torch.manual_seed(0)
    get_policy_class(cfg.type)(cfg).save_pretrained(path)
    for pipeline in make_pre_post_processors(cfg, dataset_stats=stats):
        pipeline.save_pretrained(path)
    return path


def _actions(path: Path, frame: dict) -> torch.Tensor:
    cfg = PreTrainedConfig.from_pretrained(path)
    pre, post = make_pre_post_processors(cfg, pretrained_path=str(path))
    policy = get_policy_class(cfg.type).from_pretrained(path)
    policy.reset()
    batch = prepare_observation_for_inference(dict(frame), torch.device("cpu"), "", "actionflow_sim")
    torch.manual_seed(1)
    return post(policy.select_action(pre(batch)))


@pytest.mark.parametrize("kind", ["actionflow", "euclidean_flow", "diffusion"])
def test_prepared_checkpoint_acts_on_the_flat_observation_as_on_the_dataset(kind, tmp_path):
    path = tmp_path / kind
    if kind == "actionflow":
        save_untrained_actionflow(TASK, path)
    else:
        _save_euclidean(kind, path)
    spec = get_task(TASK)
    rng = np.random.default_rng(0)
    env_obs = {
        ENV_AGENT_POS: rng.normal(size=11).astype(np.float32),
        ENV_STATE: rng.normal(size=9).astype(np.float32),
        ENV_POSES: rng.normal(size=(2, 7)).astype(np.float32),
    }
    env_obs[ENV_POSES][:, 3:] /= np.linalg.norm(env_obs[ENV_POSES][:, 3:], axis=1, keepdims=True)
    dataset_frame = {ENV_TO_DATASET_KEY[k]: v for k, v in env_obs.items()}
    names = observation_names(spec)
    flat = flatten_observation(env_obs, names)
    robot_frame = {STATE_KEY: np.array([flat[k] for k in names], dtype=np.float32)}

    if kind == "diffusion":
        # LeRobot's own preprocessor: refuses the robot's flat state (wrong width) until prepared.
        with pytest.raises(Exception, match=r"observation\.state|shape|size"):
            _actions(path, robot_frame)
        assert add_robot_observation_step(path)
        assert not add_robot_observation_step(path)  # idempotent
    else:
        # Our policies' preprocessors carry the step from the start.
        assert not add_robot_observation_step(path)
    torch.testing.assert_close(_actions(path, robot_frame), _actions(path, dataset_frame), rtol=0, atol=0)
