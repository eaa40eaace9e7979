"""Every registered task: make, seeded reset, observation schema, step, render, control,
action validation and success checks."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch
from env_success_states import construct_success, set_lid, threading

import lerobot_actionflow.envs as af_envs
from lerobot_actionflow import geometry as G
from lerobot_actionflow.envs import get_task
from lerobot_actionflow.rotations import matrix_to_rotation_6d, yaw_matrix

ALL_TASK_IDS = list(af_envs.GYM_IDS)

#: robosuite's own observation keys for the object tokens, per task (scalar-last quaternions).
ROBOSUITE_OBJECT_KEYS = {
    "Lift": ["cube"],
    "Can": ["Can", None],
    "Square": ["SquareNut", None],
    "ToolHang": ["base", "frame", "tool"],
}


def test_all_tasks_are_registered():
    expected = {"Lift", "Can", "Square", "ToolHang"}
    expected |= {
        f"{t}_{v}"
        for t in ("StackThree", "Threading", "ThreePieceAssembly", "Coffee")
        for v in ("D0", "D1", "D2")
    }
    assert {f"lerobot_actionflow/{t}-v0" for t in expected} <= set(ALL_TASK_IDS)
    for gym_id in ALL_TASK_IDS:
        assert gym_id in gym.registry
        assert gym.registry[gym_id].max_episode_steps == get_task(gym_id).episode_length


def _hold_action(env, gripper=-1.0, dpos=(0.0, 0.0, 0.0), rot=None) -> np.ndarray:
    pos, mat = env.unwrapped.eef_pose()
    mat = mat if rot is None else rot @ mat
    return np.concatenate([pos + np.asarray(dpos), mat[:, 0], mat[:, 1], [gripper]]).astype(np.float32)


def _assert_obs_equal(a, b):
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@pytest.mark.parametrize("gym_id", ALL_TASK_IDS)
def test_seeded_reset_and_episode_are_reproducible(make_cached, gym_id):
    env = make_cached(gym_id)
    rng = np.random.default_rng(0)

    def run(seed):
        obs, _ = env.reset(seed=seed)
        traj = [obs]
        for _ in range(3):
            a = _hold_action(env, gripper=1.0, dpos=rng.uniform(-0.03, 0.03, 3))
            traj.append(env.step(a)[0])
        return traj

    state = rng.bit_generator.state
    first = run(7)
    rng.bit_generator.state = state
    second = run(7)
    for a, b in zip(first, second, strict=True):
        _assert_obs_equal(a, b)
    other, _ = env.reset(seed=8)
    assert not np.allclose(other["environment_state"], first[0]["environment_state"]), "seed has no effect"


@pytest.mark.parametrize("gym_id", ALL_TASK_IDS)
def test_same_seed_same_scene_in_a_fresh_env(make_cached, gym_id):
    """A seed fixes the scene for every env instance (another process, an eval worker), not only
    within one: robosuite draws some of the model at construction (Lift's cube size)."""
    fresh = gym.make(gym_id, render_mode=None)
    try:
        _assert_obs_equal(fresh.reset(seed=5)[0], make_cached(gym_id).reset(seed=5)[0])
    finally:
        fresh.close()


@pytest.mark.parametrize("gym_id", ALL_TASK_IDS)
def test_observation_schema(make_cached, gym_id):
    env = make_cached(gym_id)
    spec = get_task(gym_id)
    obs, info = env.reset(seed=0)
    n = spec.num_tokens
    assert set(obs) == {"poses", "agent_pos", "environment_state"}
    assert obs["poses"].shape == (n, 7) and obs["poses"].dtype == np.float32
    assert obs["agent_pos"].shape == (11,) and obs["agent_pos"].dtype == np.float32
    assert obs["environment_state"].shape == (9 * (n - 1),) and obs["environment_state"].dtype == np.float32
    assert env.observation_space.contains(obs)
    assert info == {"is_success": False}
    assert env.unwrapped.task == spec.name and env.unwrapped.task_description == spec.description
    assert env.metadata["render_fps"] == 20

    poses = torch.from_numpy(obs["poses"]).double()
    quats = poses[:, 3:]
    torch.testing.assert_close(quats.norm(dim=-1), torch.ones(n, dtype=torch.float64), atol=1e-6, rtol=0)
    assert (quats[:, 0] >= 0).all(), "quaternions must be scalar-first with w >= 0"
    rot6d = G.matrix_to_rotation_6d(G.quaternion_to_matrix(quats))
    agent = torch.from_numpy(obs["agent_pos"]).double()
    torch.testing.assert_close(agent[:3], poses[0, :3], atol=1e-6, rtol=0)
    torch.testing.assert_close(agent[3:9], rot6d[0], atol=1e-5, rtol=0)
    env_state = torch.from_numpy(obs["environment_state"]).double().reshape(n - 1, 9)
    torch.testing.assert_close(env_state[:, :3], poses[1:, :3], atol=1e-6, rtol=0)
    torch.testing.assert_close(env_state[:, 3:], rot6d[1:], atol=1e-5, rtol=0)

    # Against robosuite's own (scalar-last) observations: the convention is converted once, right.
    rs_obs = env.unwrapped.robosuite_env._get_observations(force_update=True)
    np.testing.assert_allclose(obs["poses"][0, :3], rs_obs["robot0_eef_pos"], atol=1e-6)
    eef_q = G.xyzw_to_wxyz(torch.from_numpy(rs_obs["robot0_eef_quat_site"]).double())
    assert abs(float(eef_q @ quats[0])) == pytest.approx(1.0, abs=1e-5)
    np.testing.assert_allclose(obs["agent_pos"][9:], rs_obs["robot0_gripper_qpos"], atol=1e-6)
    for row, key in enumerate(ROBOSUITE_OBJECT_KEYS.get(spec.name, []), start=1):
        if key is None:
            continue
        np.testing.assert_allclose(obs["poses"][row, :3], rs_obs[f"{key}_pos"], atol=1e-5)
        q = G.xyzw_to_wxyz(torch.from_numpy(np.asarray(rs_obs[f"{key}_quat"], dtype=np.float64)))
        assert abs(float(q @ quats[row])) == pytest.approx(1.0, abs=1e-5)


@pytest.mark.parametrize("gym_id", ALL_TASK_IDS)
def test_step_and_render(make_cached, gym_id):
    env = make_cached(gym_id)
    env.reset(seed=1)
    obs, reward, terminated, truncated, info = env.step(_hold_action(env))
    assert isinstance(reward, float) and reward == 0.0 and not terminated and not truncated
    assert info == {"is_success": False}
    assert env.observation_space.contains(obs)
    img = env.render()
    assert img.shape == (256, 256, 3) and img.dtype == np.uint8
    assert img.std() > 10, "render returned a blank image"


#: One task per robosuite env class (the variants share robot, controller and scene code).
ONE_PER_ENV_CLASS = [i for i in ALL_TASK_IDS if "_D1" not in i and "_D2" not in i]


@pytest.mark.parametrize("gym_id", ONE_PER_ENV_CLASS)
def test_pose_control_reaches_the_target(make_cached, gym_id):
    """40 steps (2 s) toward a target 8 cm away and 20 deg about z: the EEF gets there."""
    env = make_cached(gym_id)
    env.reset(seed=1)
    action = _hold_action(env, dpos=(0.05, -0.04, -0.05), rot=yaw_matrix(math.radians(20)))
    for _ in range(40):
        obs, *_ = env.step(action)
    pos, mat = env.unwrapped.eef_pose()
    assert np.linalg.norm(pos - action[:3]) < 0.01
    target = G.rotation_6d_to_matrix(torch.from_numpy(action[3:9]).double())
    err = G.geodesic_distance(torch.from_numpy(mat).double(), target)
    assert math.degrees(float(err)) < 3.0
    np.testing.assert_allclose(obs["agent_pos"][3:9], matrix_to_rotation_6d(mat), atol=1e-6)


@pytest.mark.parametrize("gym_id", ALL_TASK_IDS)
def test_success_false_at_reset_true_when_constructed(make_cached, gym_id):
    env = make_cached(gym_id)
    _, info = env.reset(seed=2)
    assert info["is_success"] is False and not env.unwrapped.is_success()
    rs = env.unwrapped.robosuite_env
    assert rs.reward(None) == 0.0  # the wrapper reads success off robosuite's sparse reward
    construct_success(env.unwrapped)
    assert env.unwrapped.is_success()
    assert rs.reward(None) == 1.0


@pytest.mark.parametrize(
    "gym_id",
    [
        i
        for i in ALL_TASK_IDS
        if any(t in i for t in ("Lift", "StackThree_D0", "ThreePieceAssembly_D0", "Coffee_D0"))
    ],
)
def test_constructed_success_survives_physics_and_terminates(make_cached, gym_id):
    env = make_cached(gym_id)
    env.reset(seed=3)
    construct_success(env.unwrapped)
    hold = _hold_action(env)
    _, reward, terminated, _, info = env.step(hold)
    assert info["is_success"] is True and reward == 1.0 and terminated is True
    if "Lift" not in gym_id:  # the assembly stands on its own
        for _ in range(10):
            _, _, _, _, info = env.step(hold)
        assert info["is_success"] is True


def test_quaternions_are_canonical_and_set_entity_pose_round_trips(make_cached):
    env = make_cached("lerobot_actionflow/ToolHang-v0").unwrapped
    env.reset(seed=0)
    q = np.array([-0.5, 0.5, -0.5, 0.5])  # w < 0: the same rotation as -q
    env.set_entity_pose("tool", [0.05, -0.2, 0.9], q)
    np.testing.assert_allclose(env.get_observation()["poses"][3], [0.05, -0.2, 0.9, *(-q)], atol=1e-6)
    env.set_entity_pose("frame", [0.1, -0.1, 0.95], q)  # a site token: moves its body accordingly
    np.testing.assert_allclose(env.get_observation()["poses"][2], [0.1, -0.1, 0.95, *(-q)], atol=1e-6)


def test_scripted_lift_grasp_succeeds(make_cached):
    """End to end through the 10-D interface: above the cube, down, close (+1), lift -> success."""
    env = make_cached("lerobot_actionflow/Lift-v0")
    obs, _ = env.reset(seed=3)
    _, rot = env.unwrapped.eef_pose()
    cube = obs["poses"][1, :3].astype(np.float64)
    info, opened = {}, None
    for offset, grip, steps in [(0.10, -1.0, 30), (0.0, -1.0, 25), (0.0, 1.0, 10), (0.15, 1.0, 40)]:
        action = np.concatenate([cube + np.array([0.0, 0.0, offset]), rot[:, 0], rot[:, 1], [grip]])
        for _ in range(steps):
            obs, _, terminated, _, info = env.step(action)
            if terminated:
                break
        if offset == 0.0 and grip < 0:
            opened = obs["agent_pos"][9] - obs["agent_pos"][10]  # finger gap with -1
    assert info["is_success"] and terminated
    assert obs["poses"][1, 2] > cube[2] + 0.01  # the cube rose
    assert opened > obs["agent_pos"][9] - obs["agent_pos"][10], "+1 must close the gripper"


def test_lift_success_threshold(make_cached):
    env = make_cached("lerobot_actionflow/Lift-v0").unwrapped
    env.reset(seed=0)
    env.set_entity_pose("cube", [0.0, 0.0, 0.8 + 0.035], [1, 0, 0, 0])
    assert not env.is_success()
    env.set_entity_pose("cube", [0.0, 0.0, 0.8 + 0.045], [1, 0, 0, 0])
    assert env.is_success()


def test_stack_three_needs_both_cubes_stacked(make_cached):
    env = make_cached("lerobot_actionflow/StackThree_D0-v0").unwrapped
    env.reset(seed=0)
    construct_success(env)
    assert env.is_success()
    env.set_entity_pose("cubeC", [0.15, 0.15, 0.82], [1, 0, 0, 0])  # C back on the table
    assert not env.is_success()
    construct_success(env)
    env.set_entity_pose("cubeA", [-0.15, 0.1, 0.82], [1, 0, 0, 0])  # A on the table, C floating
    assert not env.is_success()


def test_threading_needs_the_tip_in_the_ring(make_cached):
    env = make_cached("lerobot_actionflow/Threading_D0-v0").unwrapped
    env.reset(seed=0)
    threading(env, along_axis=0.005)
    assert env.is_success()
    threading(env, along_axis=-0.02)  # tip 2 cm short of the ring
    assert not env.is_success()


def test_three_piece_assembly_needs_both_pieces_inserted(make_cached):
    env = make_cached("lerobot_actionflow/ThreePieceAssembly_D0-v0").unwrapped
    env.reset(seed=0)
    construct_success(env)
    assert env.is_success()
    base = env.get_observation()["poses"][1].astype(np.float64)
    env.set_entity_pose("piece2", [0.15, 0.2, 0.815], [1, 0, 0, 0])  # piece 2 back on the table
    assert not env.is_success()
    construct_success(env)
    env.set_entity_pose(
        "piece1", base[:3] + np.array([0.0, 0.0, 0.0175 + 0.02]), base[3:]
    )  # resting on the walls
    env.set_entity_pose("piece2", base[:3] + np.array([0.0, 0.0, 0.0175 + 0.02 + 0.0225]), base[3:])
    assert not env.is_success()
    env.set_entity_pose("piece1", base[:3] + np.array([0.025, 0.0, 0.0175]), base[3:])  # beside the socket
    assert not env.is_success()


def test_coffee_needs_pod_in_holder_and_lid_closed(make_cached):
    env = make_cached("lerobot_actionflow/Coffee_D0-v0").unwrapped
    env.reset(seed=0)
    assert env.robosuite_env.lid_angle == pytest.approx(math.radians(100))  # starts open
    construct_success(env)
    assert env.is_success()
    set_lid(env, math.radians(20))  # lid ajar
    assert not env.is_success()
    set_lid(env, math.radians(10))
    assert env.is_success()
    holder = env.get_observation()["poses"][2, :3].astype(np.float64)
    env.set_entity_pose("pod", holder + np.array([0.0, 0.0, 0.04]), [1, 0, 0, 0])  # pod above the holder
    assert not env.is_success()


def test_stack_three_variants_widen_the_placement(make_cached):
    spread = {}
    for v in ("D0", "D1"):
        env = make_cached(f"lerobot_actionflow/StackThree_{v}-v0")
        xy = np.concatenate([env.reset(seed=s)[0]["poses"][1:, :2] for s in range(8)])
        spread[v] = np.abs(xy).max()
    assert spread["D0"] <= 0.10 + 1e-6 < spread["D1"] <= 0.20 + 1e-6


@pytest.mark.parametrize(
    ("action", "match"),
    [
        (np.zeros(9), r"shape \(10,\)"),
        (np.zeros((1, 10)), r"shape \(10,\)"),
        (np.array([0.0, 0, 1, 1, 0, 0, 0, 1, 0, np.nan]), r"non-finite.*\[9\]"),
        (np.array([0.0, np.inf, 1, 1, 0, 0, 0, 1, 0, 0]), r"non-finite.*\[1\]"),
        (np.array([0.0, 0, 1, 0, 0, 0, 0, 1, 0, 0]), "6D rotation"),
        (np.array([0.0, 0, 1, 1, 0, 0, 2, 0, 0, 0]), "6D rotation"),
        (["a"] * 10, "numeric"),
    ],
    ids=["short", "batched", "nan", "inf", "zero-rot", "parallel-rot", "strings"],
)
def test_bad_actions_raise_value_error(make_cached, action, match):
    env = make_cached("lerobot_actionflow/Lift-v0")
    env.reset(seed=0)
    before = env.unwrapped.robosuite_env.timestep
    with pytest.raises(ValueError, match=match):
        env.step(action)
    assert env.unwrapped.robosuite_env.timestep == before, "a rejected action must not step the sim"


def test_out_of_workspace_positions_and_gripper_are_clipped(make_cached):
    env = make_cached("lerobot_actionflow/Lift-v0").unwrapped
    spec = get_task("Lift")
    a = np.array([5.0, -5.0, 0.0, 1, 0, 0, 0, 1, 0, 3.0])
    out = env.to_robosuite_action(a)
    np.testing.assert_allclose(
        out[:3], [spec.workspace_high[0], spec.workspace_low[1], spec.workspace_low[2]]
    )
    assert out[6] == 1.0
    np.testing.assert_allclose(out[3:6], 0.0, atol=1e-12)  # identity rotation -> zero axis-angle
