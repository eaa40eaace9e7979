"""Point-cloud observations: geometry against the simulator, robot/table removal, cropping,
farthest-point sampling (determinism and the greedy property), and the env / LeRobot options."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from lerobot_actionflow.envs.point_cloud import PointCloudSensor, farthest_point_sample
from lerobot_actionflow.envs.point_cloud_config import PointCloudConfig
from lerobot_actionflow.rotations import quaternion_to_matrix
from lerobot_actionflow.schema import ENV_POINT_CLOUD, POINT_CLOUD_KEY

#: Back-projected points must lie on the surface they come from to this tolerance (metres); on
#: software EGL the largest error measured is 3e-7 m (float32 depth), the tolerance leaves room
#: for other renderers' depth buffers.
SURFACE_TOL = 0.001
#: Lift's cube, put at a known pose: yawed 30 degrees about z, resting on the table top (z 0.8).
CUBE_POS = np.array([0.03, -0.02, 0.8 + 0.021])
CUBE_QUAT = np.array([np.cos(np.pi / 12), 0.0, 0.0, np.sin(np.pi / 12)])


@pytest.fixture(scope="module")
def lift_pc():
    env = gym.make("lerobot_actionflow/Lift-v0", point_cloud={"num_points": 256})
    yield env.unwrapped
    env.close()


def _cube_at_known_pose(env):
    env.reset(seed=0)
    env.set_body_pose("cube_main", CUBE_POS, CUBE_QUAT)
    m = env.robosuite_env.sim.model._model
    gid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "cube_g0")
    half = np.asarray(m.geom_size[gid], dtype=np.float64)
    return half


def _surface_distance(points: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Unsigned distance of world points to the surface of the cube box at its known pose."""
    local = (points - CUBE_POS) @ quaternion_to_matrix(CUBE_QUAT)  # R^T (p - c), row-wise
    q = np.abs(local) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return np.abs(outside + inside)


def test_cube_points_lie_on_its_faces_and_nothing_else_remains(lift_pc):
    half = _cube_at_known_pose(lift_pc)
    sensor = lift_pc.point_cloud_sensor
    pts = sensor.fused_points()
    assert len(pts) > 50
    assert _surface_distance(pts, half).max() < SURFACE_TOL
    # Both cameras contribute, and together they see the top face and side faces.
    local = (pts - CUBE_POS) @ quaternion_to_matrix(CUBE_QUAT)
    on_top = np.abs(local[:, 2] - half[2]) < SURFACE_TOL
    on_side = np.abs(np.abs(local[:, :2]) - half[:2]).min(axis=1) < SURFACE_TOL
    assert on_top.sum() > 10 and (on_side & ~on_top).sum() > 10
    # The observation is a subset of those points, float32 (M, 3).
    cloud = lift_pc.get_observation()[ENV_POINT_CLOUD]
    assert cloud.shape == (256, 3) and cloud.dtype == np.float32
    assert _surface_distance(cloud.astype(np.float64), half).max() < SURFACE_TOL


def test_the_raw_depth_holds_table_and_robot_points_that_removal_drops(lift_pc):
    """Control: before removal the cameras see the table and the arm (off the cube's faces)."""
    half = _cube_at_known_pose(lift_pc)
    sensor = lift_pc.point_cloud_sensor
    m = lift_pc.robosuite_env.sim.model._model
    robot_root = m.body_rootid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "robot0_base")]
    raw, geoms = sensor.camera_points(0)
    bodies_root = m.body_rootid[m.geom_bodyid[geoms]]
    assert (bodies_root == robot_root).sum() > 100  # the arm is in view
    assert (_surface_distance(raw, half) > 0.01).mean() > 0.5  # most raw points are not the cube
    on_table = np.abs(raw[:, 2] - 0.8) < SURFACE_TOL
    assert on_table.sum() > 100


def test_one_pass_depth_and_geoms_equal_mujocos_own_depth_and_segmentation_passes(lift_pc):
    """The geom ids read from the depth pass's colour buffer are those of MuJoCo's segmentation
    pass, pixel for pixel, and the depth is its depth pass's."""
    _cube_at_known_pose(lift_pc)
    renderer = lift_pc.point_cloud_sensor._renderer
    depth, geoms = renderer.render_depth_and_geoms("agentview", 64, 80)
    reference = mujoco.Renderer(renderer._model, 64, 80)
    try:
        reference.update_scene(renderer._data, camera="agentview", scene_option=renderer._geometry_option)
        reference.enable_depth_rendering()
        expected_depth = reference.render()
        reference.disable_depth_rendering()
        reference.enable_segmentation_rendering()
        seg = reference.render()
    finally:
        reference.close()
    expected_geoms = np.where(seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM, seg[..., 0], -1)
    assert np.array_equal(depth, expected_depth)
    assert np.array_equal(geoms, expected_geoms)
    assert len(np.unique(geoms)) > 5  # not a trivially uniform image


def test_image_rows_flipped_the_wrong_way_put_points_off_the_cube(lift_pc, monkeypatch):
    """Control for the orientation convention: OpenGL's bottom-up rows, read as top-down, move
    the points far off the faces."""
    half = _cube_at_known_pose(lift_pc)
    renderer = lift_pc.point_cloud_sensor._renderer
    right = renderer.render_depth_and_geoms
    monkeypatch.setattr(renderer, "render_depth_and_geoms", lambda *a: tuple(x[::-1] for x in right(*a)))
    pts = lift_pc.point_cloud_sensor.fused_points()
    assert len(pts) == 0 or _surface_distance(pts, half).max() > 0.05


def test_crop_box_bounds_the_points(lift_pc):
    low, high = (-0.5, -0.5, 0.8), (0.5, 0.5, 0.83)  # cuts the cube at 0.83 m
    config = PointCloudConfig(num_points=64, box_low=low, box_high=high)
    sim, removed = lift_pc.robosuite_env.sim, ("robot0_base", "table")
    sensor = PointCloudSensor(sim, lift_pc._renderer, config, None, None, removed)  # on the env's renderer
    half = _cube_at_known_pose(lift_pc)
    pts = sensor.fused_points()
    assert len(pts) > 10
    assert (pts >= low).all() and (pts <= high).all()
    assert _surface_distance(pts, half).max() < SURFACE_TOL
    assert (pts[:, 2] > 0.825).any()  # the crop cut through the cube, not below it


def test_can_in_the_bins_arena_keeps_only_the_can():
    """Can has no table and no side camera: its cameras are the task's own, the bins and the
    target-cell markers are removed, and what remains is the can (about 0.04 m in radius)."""
    env = gym.make("lerobot_actionflow/Can-v0", point_cloud={"num_points": 64})
    try:
        obs, _ = env.reset(seed=0)
        assert env.unwrapped.point_cloud_sensor.cameras == ("agentview", "birdview")
        can = obs["poses"][1, :3]
        pts = env.unwrapped.point_cloud_sensor.fused_points()
        assert len(pts) > 20
        assert np.linalg.norm(pts - can, axis=1).max() < 0.07
    finally:
        env.close()


def test_same_state_same_cloud_and_the_space_contains_it(lift_pc):
    a = lift_pc.reset(seed=3)[0]
    b = lift_pc.reset(seed=3)[0]
    np.testing.assert_array_equal(a[ENV_POINT_CLOUD], b[ENV_POINT_CLOUD])
    assert lift_pc.observation_space.contains(a)


# -------------------------------------------------------------- farthest-point sampling
def _greedy_gaps(points: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """For each k >= 1: (farthest distance of any point to the chosen set idx[:k]) minus (the
    distance of idx[k] to that set). Zero everywhere for a farthest-point sample."""
    d = np.linalg.norm(points[:, None] - points[idx][None], axis=-1)  # (K, M)
    running = np.minimum.accumulate(d, axis=1)  # running[:, k] = dist to idx[:k + 1]
    best = running[:, :-1].max(axis=0)
    got = running[idx[1:], np.arange(len(idx) - 1)]
    return best - got


def test_fps_chooses_the_farthest_point_each_step_and_random_choice_does_not():
    pts = np.random.default_rng(0).normal(size=(400, 3))
    idx = farthest_point_sample(pts, 64, seed=1)
    assert len(np.unique(idx)) == 64
    np.testing.assert_allclose(_greedy_gaps(pts, idx), 0.0, atol=1e-12)
    rand = np.random.default_rng(1).choice(400, 64, replace=False)
    assert _greedy_gaps(pts, rand).max() > 0.1  # control: the law fails for a random subset


def test_fps_is_deterministic_per_seed():
    pts = np.random.default_rng(2).uniform(size=(300, 3))
    np.testing.assert_array_equal(
        farthest_point_sample(pts, 50, seed=7), farthest_point_sample(pts, 50, seed=7)
    )
    seeds = {int(farthest_point_sample(pts, 50, seed=s)[0]) for s in range(5)}
    assert len(seeds) > 1  # the seed picks the start


@pytest.mark.parametrize("k", [300, 20])  # more points than the sample, and fewer (cyclic)
def test_a_prefix_of_an_fps_cloud_is_the_smaller_fps_cloud(k):
    """What ``point_cloud_points`` relies on: the first N of an M-point sample = the N-point sample."""
    pts = np.random.default_rng(4).uniform(size=(k, 3))
    full = farthest_point_sample(pts, 64, seed=3)
    for n in (1, 16, 40, 64):
        np.testing.assert_array_equal(full[:n], farthest_point_sample(pts, n, seed=3))
    shuffled = np.random.default_rng(5).permutation(full)  # control: another order of the same points
    assert not np.array_equal(shuffled[:16], farthest_point_sample(pts, 16, seed=3))


def test_fps_pads_by_cyclic_repetition_when_points_are_few():
    pts = np.random.default_rng(3).uniform(size=(5, 3))
    idx = farthest_point_sample(pts, 12)
    np.testing.assert_array_equal(idx[5:10], idx[:5])
    assert sorted(idx[:5]) == list(range(5))
    assert sorted(np.bincount(idx, minlength=5)) == [2, 2, 2, 3, 3]  # floor / ceil of 12 / 5


@pytest.mark.parametrize("bad", [np.zeros((0, 3)), np.zeros((4, 2)), np.zeros(3)])
def test_fps_rejects_bad_points(bad):
    with pytest.raises(ValueError, match="shape"):
        farthest_point_sample(bad, 4)


# -------------------------------------------------------------- options
def test_point_cloud_config_rejects_bad_settings():
    with pytest.raises(ValueError, match="two or more cameras"):
        PointCloudConfig(cameras=("agentview",))
    with pytest.raises(ValueError, match="low < high"):
        PointCloudConfig(box_low=(0, 0, 1), box_high=(1, 1, 0.5))
    with pytest.raises(ValueError, match="together"):
        PointCloudConfig(box_low=(0, 0, 0))
    with pytest.raises(TypeError, match="point_cloud"):
        PointCloudConfig.coerce("yes")
    assert PointCloudConfig.coerce(True) == PointCloudConfig()
    assert PointCloudConfig(cameras="").cameras is None  # the task's cameras
    assert PointCloudConfig.coerce(False) is None


def test_unknown_point_cloud_camera_names_the_known_ones():
    with pytest.raises(ValueError, match=r"no camera 'nope'.*agentview"):
        gym.make("lerobot_actionflow/Lift-v0", point_cloud={"cameras": ("agentview", "nope")})


def test_lerobot_env_config_adds_the_point_cloud_feature():
    from lerobot.configs import FeatureType
    from lerobot.envs.utils import env_to_policy_features

    from lerobot_actionflow.envs.configuration import ActionFlowEnvConfig

    cfg = ActionFlowEnvConfig(
        task="Lift", point_cloud=True, point_cloud_points=128, point_cloud_cameras="agentview,birdview"
    )
    feats = env_to_policy_features(cfg)
    assert feats[POINT_CLOUD_KEY].shape == (128, 3) and feats[POINT_CLOUD_KEY].type is FeatureType.STATE
    assert cfg.gym_kwargs["point_cloud"]["cameras"] == ("agentview", "birdview")
    assert POINT_CLOUD_KEY not in env_to_policy_features(ActionFlowEnvConfig(task="Lift"))
    assert ActionFlowEnvConfig(task="Lift").gym_kwargs["point_cloud"] is False
    with pytest.raises(ValueError, match="two or more cameras"):
        ActionFlowEnvConfig(task="Lift", point_cloud=True, point_cloud_cameras="agentview")
