"""The simulated robot: real-time stepping, the dataset's observations, strict actions, and
episodes that end on success or time."""

import json
import time

import gymnasium as gym
import numpy as np
import pytest
from lerobot.robots import make_robot_from_config
from lerobot.utils.feature_utils import hw_to_dataset_features

from lerobot_actionflow.envs.tasks import CONTROL_FREQ
from lerobot_actionflow.robots.actionflow_sim import ActionFlowSimConfig
from lerobot_actionflow.robots.layout import action_names, split_flat_observation
from lerobot_actionflow.schema import ENV_AGENT_POS, ENV_POSES, ENV_STATE, STATE_KEY, image_key


@pytest.fixture
def make_sim(tmp_path):
    robots = []

    def make(**kw):
        kw = {"task": "Lift", "on_done": "hold", "calibration_dir": tmp_path / "calib", **kw}
        robot = make_robot_from_config(ActionFlowSimConfig(**kw))
        robot.connect()
        robots.append(robot)
        return robot

    yield make
    for r in robots:
        if r.is_connected:
            r.disconnect()


def _flat(robot, obs) -> np.ndarray:
    return np.array([obs[k] for k in robot._obs_names], dtype=np.float32)


def _eef_action(robot, obs, dz=0.0, gripper=-1.0) -> dict:
    names = action_names()
    pose9 = split_flat_observation(_flat(robot, obs), robot.spec.num_tokens)[STATE_KEY][:9].astype(float)
    pose9[2] += dz
    return {**dict(zip(names[:9], pose9.tolist(), strict=True)), names[9]: gripper}


def _wait_for(predicate, timeout: float) -> bool:
    end = time.perf_counter() + timeout
    while time.perf_counter() < end:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def test_simulation_advances_on_the_wall_clock_and_holds_the_last_target(make_sim):
    # Bounds loose enough for a starved CPU (a late step is skipped, never made up in a burst).
    t0 = time.perf_counter()
    idle = make_sim(wait_for_first_action=False)
    assert _wait_for(lambda: idle.sim_steps >= 5, timeout=5.0), idle.sim_steps
    assert idle.sim_steps <= (time.perf_counter() - t0) * CONTROL_FREQ + 1  # never ahead of the clock

    # Control: a robot waiting for its first action does not step; once it has one, it steps
    # without further actions, applying the held target (the EEF climbs 5 cm).
    waiting = make_sim(wait_for_first_action=True)
    time.sleep(0.3)
    assert waiting.sim_steps == 0
    obs0 = waiting.get_observation()
    waiting.send_action(_eef_action(waiting, obs0, dz=0.05))
    z0 = obs0["agent_pos.eef.z.pos"]
    climbed = _wait_for(lambda: waiting.get_observation()["agent_pos.eef.z.pos"] - z0 > 0.03, timeout=5.0)
    assert climbed, (waiting.sim_steps, waiting.get_observation()["agent_pos.eef.z.pos"] - z0)


def test_observations_are_the_datasets(make_sim):
    robot = make_sim(seed=7, cameras="wrist", camera_height=24, camera_width=32)
    obs = robot.get_observation()
    assert set(obs) == set(robot.observation_features)
    env = gym.make(robot.spec.gym_id, disable_env_checker=True)
    env_obs, _ = env.reset(seed=7)
    env.close()
    parts = split_flat_observation(_flat(robot, obs), robot.spec.num_tokens)
    np.testing.assert_array_equal(parts["observation.poses"], env_obs[ENV_POSES])
    np.testing.assert_array_equal(parts[STATE_KEY], env_obs[ENV_AGENT_POS])
    np.testing.assert_array_equal(parts["observation.environment_state"], env_obs[ENV_STATE])
    assert obs["wrist"].shape == (24, 32, 3) and obs["wrist"].dtype == np.uint8
    assert obs["wrist"].std() > 0  # a rendered scene, not a blank buffer
    # What LeRobot makes of the features: one flat state, one camera image.
    ds = hw_to_dataset_features(robot.observation_features, "observation")
    assert ds[STATE_KEY]["shape"] == (16 * robot.spec.num_tokens + 2,)
    assert ds[image_key("wrist")]["shape"] == (24, 32, 3)


def test_malformed_actions_are_refused_and_leave_the_target(make_sim):
    robot = make_sim()
    good = _eef_action(robot, robot.get_observation())
    target = robot._target.copy()
    bad = [
        ({k: v for k, v in good.items() if k != "gripper.pos"}, r"missing \['gripper.pos'\]"),
        ({**good, "target.y.pos": float("inf")}, "'target.y.pos' is not finite"),
        ({**good, **{f"target.r{i}.pos": 0.0 for i in ("00", "10", "20")}}, "rotation|rot6d|degenerate"),
    ]
    for action, match in bad:
        with pytest.raises(ValueError, match=match):
            robot.send_action(action)
    np.testing.assert_array_equal(robot._target, target)
    assert robot.sim_steps == 0  # no refused action started the clock
    sent = robot.send_action(good)
    assert list(sent) == action_names()


def test_episodes_end_on_success_then_on_time_and_are_reported(make_sim, tmp_path):
    results = tmp_path / "episodes.jsonl"
    robot = make_sim(num_episodes=2, episode_length=4, seed=3, results_path=str(results))
    # Lift the cube above the success height while the simulation waits for its first action.
    env = robot._env.unwrapped
    cube_pos = np.asarray(env.get_observation()[ENV_POSES][1, :3])
    env.set_body_pose("cube_main", cube_pos + np.array([0.0, 0.0, 0.2]), [1, 0, 0, 0])
    robot.send_action(_eef_action(robot, robot.get_observation()))
    assert robot.done.wait(3.0), robot.episodes
    first, second = robot.episodes
    assert (first.success, first.steps, first.seed) == (True, 1, 3)
    assert (second.success, second.steps, second.seed) == (False, 4, 4)
    lines = [json.loads(x) for x in results.read_text().splitlines()]
    assert [x["success"] for x in lines] == [True, False] and lines[0]["task"] == "Lift"
    steps = robot.sim_steps
    time.sleep(0.2)
    assert robot.sim_steps == steps  # "hold": frozen after the last episode


def test_config_errors_name_the_field():
    with pytest.raises(KeyError, match="unknown task 'Lyft'"):
        ActionFlowSimConfig(task="Lyft")
    with pytest.raises(ValueError, match=r"robot\.on_done"):
        ActionFlowSimConfig(on_done="exit")
    with pytest.raises(ValueError, match=r"robot\.real_time_factor"):
        ActionFlowSimConfig(real_time_factor=0)
    assert ActionFlowSimConfig(task="Lift-v0").episode_length > 0
