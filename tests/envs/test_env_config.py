"""LeRobot env type ``actionflow``: LeRobot's own ``make_env`` builds our envs and
``preprocess_observation`` maps their observations onto the dataset schema."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from lerobot.configs import FeatureType
from lerobot.envs.configs import EnvConfig
from lerobot.envs.factory import make_env, make_env_config
from lerobot.envs.utils import env_to_policy_features, preprocess_observation
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE, OBS_STR

from lerobot_actionflow.envs.configuration import ActionFlowEnvConfig
from lerobot_actionflow.registry import PLUGIN_MODULES


def test_registered_as_lerobot_env_type():
    assert "lerobot_actionflow.envs.configuration" in PLUGIN_MODULES
    assert EnvConfig.get_choice_class("actionflow") is ActionFlowEnvConfig
    cfg = make_env_config("actionflow", task="Square")
    assert isinstance(cfg, ActionFlowEnvConfig)
    assert cfg.gym_id == "lerobot_actionflow/Square-v0" and cfg.episode_length == 400


def test_policy_features_follow_the_schema():
    cfg = ActionFlowEnvConfig(task="ToolHang", cameras="wrist,agentview", observation_height=64)
    feats = env_to_policy_features(cfg)
    assert feats["action"].shape == (10,) and feats["action"].type is FeatureType.ACTION
    assert feats["observation.poses"].shape == (4, 7)
    assert feats["observation.state"].shape == (11,)
    assert feats["observation.environment_state"].shape == (27,)
    assert feats["observation.environment_state"].type is FeatureType.ENV
    assert feats["observation.images.wrist"].shape == (3, 64, 84)
    assert feats["observation.images.agentview"].type is FeatureType.VISUAL


def test_features_map_uses_lerobots_key_names():
    cfg = ActionFlowEnvConfig(task="Lift", cameras="wrist")
    assert cfg.features_map == {
        ACTION: ACTION,
        "poses": f"{OBS_STR}.poses",
        "agent_pos": OBS_STATE,
        "environment_state": OBS_ENV_STATE,
        "pixels/wrist": f"{OBS_IMAGES}.wrist",
    }
    assert set(cfg.features) == set(cfg.features_map)


def test_bad_config_values_are_rejected():
    with pytest.raises(KeyError, match="unknown task"):
        ActionFlowEnvConfig(task="Nope")
    with pytest.raises(ValueError, match="scene transform"):
        ActionFlowEnvConfig(task="Lift", scene_x=(0.0, 0.5))


def test_make_env_vector_env_and_preprocess_observation():
    cfg = ActionFlowEnvConfig(
        task="Lift", cameras="wrist,agentview", observation_height=48, observation_width=64
    )
    envs = make_env(cfg, n_envs=2, use_async_envs=False)
    vec = envs["actionflow"][0]
    try:
        assert vec.num_envs == 2
        obs, info = vec.reset(seed=[0, 1])
        assert not info["is_success"].any()
        batch = preprocess_observation(obs)
        shapes = {k: tuple(v.shape) for k, v in batch.items()}
        assert shapes == {
            "observation.poses": (2, 2, 7),
            "observation.state": (2, 11),
            "observation.environment_state": (2, 9),
            "observation.images.wrist": (2, 3, 48, 64),
            "observation.images.agentview": (2, 3, 48, 64),
        }
        assert all(v.dtype == torch.float32 for v in batch.values())
        assert (
            0.0 <= batch["observation.images.wrist"].min() and batch["observation.images.wrist"].max() <= 1.0
        )
        # The two sub-envs were seeded differently.
        assert not torch.equal(
            batch["observation.environment_state"][0], batch["observation.environment_state"][1]
        )
        assert list(vec.call("task")) == ["Lift", "Lift"]
        assert next(iter(vec.call("task_description"))) == "Lift the red cube off the table."
        assert list(vec.call("_max_episode_steps")) == [400, 400]
        assert vec.metadata["render_fps"] == 20
        action = np.concatenate([obs["agent_pos"][:, :9], -np.ones((2, 1), np.float32)], axis=1)
        obs, reward, terminated, truncated, info = vec.step(action)
        assert reward.shape == (2,) and not terminated.any() and not truncated.any()
        frames = np.stack(vec.call("render"))
        assert frames.shape == (2, 256, 256, 3) and frames.dtype == np.uint8
    finally:
        vec.close()


def test_make_env_async_workers_build_and_step():
    """Forkserver workers import our config module again and must find the gym ids there."""
    cfg = ActionFlowEnvConfig(task="StackThree_D1")
    vec = make_env(cfg, n_envs=2, use_async_envs=True)["actionflow"][0]
    try:
        assert type(vec).__name__ == "AsyncVectorEnv"
        obs, _ = vec.reset(seed=[3, 3])
        np.testing.assert_array_equal(obs["poses"][0], obs["poses"][1])  # same seed, same state
        action = np.concatenate([obs["agent_pos"][:, :9], np.ones((2, 1), np.float32)], axis=1)
        obs, _, terminated, _, _ = vec.step(action)
        assert obs["poses"].shape == (2, 4, 7) and not terminated.any()
        assert list(vec.call("task")) == ["StackThree_D1", "StackThree_D1"]
    finally:
        vec.close()


def test_lerobot_envs_empty_mujocos_asset_cache_and_plain_envs_keep_it():
    import gymnasium as gym
    import mujoco

    cache = mujoco.mj_getCache()
    cfg = ActionFlowEnvConfig(task="Lift")
    assert cfg.gym_kwargs["asset_cache"] is False
    env = gym.make(cfg.gym_id, asset_cache=cfg.gym_kwargs["asset_cache"])
    try:
        assert mujoco.mj_getCacheSize(cache) == 0
    finally:
        env.close()
    env = gym.make(cfg.gym_id)
    try:
        assert mujoco.mj_getCacheSize(cache) > 0
    finally:
        env.close()
