"""Scene transform: the whole initial layout (and optionally the EEF) moves by one planar
rigid motion, reproducibly, within the documented range."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from env_success_states import construct_success

from lerobot_actionflow.envs import SceneTransform, get_task
from lerobot_actionflow.envs.scene_mover import planar_motion
from lerobot_actionflow.rotations import apply, quaternion_to_matrix, yaw_matrix


@pytest.fixture(scope="module")
def transformed_envs():
    made = {}

    def _make(task, **kw):
        key = (task, tuple(sorted(kw.items())))
        if key not in made:
            made[key] = gym.make(f"lerobot_actionflow/{task}-v0", scene_transform=SceneTransform(**kw))
        return made[key]

    yield _make
    for env in made.values():
        env.close()


def _expected(poses, yaw, shift, pivot):
    """``p' = Rz(yaw) (p - c) + c + t``, ``R' = Rz(yaw) R``, written out."""
    c, s = math.cos(yaw), math.sin(yaw)
    d = poses[:, :3].astype(np.float64) - [pivot[0], pivot[1], 0.0]
    pos = np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=-1)
    pos += [pivot[0] + shift[0], pivot[1] + shift[1], 0.0]
    return pos, yaw_matrix(yaw) @ quaternion_to_matrix(poses[:, 3:])


def test_planar_motion_is_the_documented_rigid_motion():
    x = np.random.default_rng(0).normal(size=(5, 3))
    poses = np.concatenate([x, np.tile([1.0, 0.0, 0.0, 0.0], (5, 1))], axis=1)
    r, p = planar_motion(0.7, (0.05, -0.03), (0.1, -0.2))
    np.testing.assert_allclose(r, yaw_matrix(0.7), atol=0)
    np.testing.assert_allclose(
        apply(r, p, x), _expected(poses, 0.7, (0.05, -0.03), (0.1, -0.2))[0], atol=1e-12
    )


@pytest.mark.parametrize("task", ["StackThree_D0", "Square"])
@pytest.mark.parametrize("move_robot", [True, False])
def test_layout_moves_rigidly(make_cached, transformed_envs, task, move_robot):
    yaw, tx, ty = 0.7, 0.05, -0.03
    base, _ = make_cached(f"lerobot_actionflow/{task}-v0").reset(seed=5)
    env = transformed_envs(task, yaw=yaw, x=tx, y=ty, move_robot=move_robot)
    moved, _ = env.reset(seed=5)
    pos, mats = _expected(base["poses"], yaw, (tx, ty), get_task(task).pivot_xy)
    got = quaternion_to_matrix(moved["poses"][:, 3:])
    np.testing.assert_allclose(moved["poses"][1:, :3], pos[1:], atol=1e-5)
    np.testing.assert_allclose(got[1:], mats[1:], atol=1e-5)
    if move_robot:
        np.testing.assert_allclose(moved["poses"][0, :3], pos[0], atol=1e-3)
        np.testing.assert_allclose(got[0], mats[0], atol=5e-3)
        # The controller holds the moved pose: the arm is at rest there.
        hold = np.concatenate([moved["poses"][0, :3], got[0][:, 0], got[0][:, 1], [-1.0]])
        for _ in range(10):
            obs = env.step(hold)[0]
        assert np.linalg.norm(obs["poses"][0, :3] - moved["poses"][0, :3]) < 0.005
    else:
        np.testing.assert_allclose(moved["poses"][0], base["poses"][0], atol=1e-6)


def test_success_follows_moved_fixtures(transformed_envs):
    env = transformed_envs("Square", yaw=-1.2, x=0.08, y=0.06)
    _obs, info = env.reset(seed=0)
    assert not info["is_success"]
    construct_success(env.unwrapped)  # nut onto the moved peg
    assert env.unwrapped.is_success()


def test_sampled_ranges_are_reproducible_and_in_range(make_cached, transformed_envs):
    lo, hi = -math.pi / 2, math.pi / 2
    env = transformed_envs("Lift", yaw=(lo, hi), x=(-0.1, 0.1), move_robot=True)
    base = make_cached("lerobot_actionflow/Lift-v0")
    yaws = []
    for seed in (0, 1, 2):
        ref = base.reset(seed=seed)[0]["poses"]
        a = env.reset(seed=seed)[0]["poses"]
        np.testing.assert_array_equal(a, env.reset(seed=seed)[0]["poses"])
        r_ref, r_new = quaternion_to_matrix(ref[0, 3:]), quaternion_to_matrix(a[0, 3:])
        rel = r_new @ r_ref.T  # a yaw about z
        assert abs(rel[2, 2] - 1) < 1e-2
        yaws.append(math.atan2(rel[1, 0], rel[0, 0]))
    assert all(lo - 1e-3 <= y <= hi + 1e-3 for y in yaws)
    assert len({round(y, 3) for y in yaws}) == 3, "yaw is not sampled per reset"


@pytest.mark.parametrize(
    "kwargs",
    [{"x": 0.2}, {"y": (-0.3, 0.0)}, {"yaw": 2.0, "move_robot": True}, {"yaw": 4.0}, {"yaw": (1.0, 0.0)}],
)
def test_out_of_range_transforms_are_rejected(kwargs):
    with pytest.raises(ValueError, match="scene transform"):
        SceneTransform(**kwargs)


def test_transform_never_moves_objects_off_the_table(transformed_envs):
    env = transformed_envs("StackThree_D2", yaw=(-math.pi, math.pi), x=(-0.1, 0.1), y=(-0.1, 0.1))
    for seed in range(6):
        xy = env.reset(seed=seed)[0]["poses"][1:, :2]
        assert np.abs(xy).max() <= 0.4 - 0.02 + 1e-6
    fixed = gym.make("lerobot_actionflow/StackThree_D2-v0", scene_transform={"x": 0.1, "y": 0.1})
    try:
        with pytest.raises(ValueError, match="off the table"):
            for seed in range(20):  # some D2 layout reaches y > 0.28
                fixed.reset(seed=seed)
    finally:
        fixed.close()


def test_task_without_transform_support_rejects_it():
    with pytest.raises(ValueError, match="does not support a scene transform"):
        gym.make("lerobot_actionflow/Can-v0", scene_transform={"yaw": 0.5})
