"""The numpy rotation layer (:mod:`lerobot_actionflow.rotations`) agrees with the torch
geometry package, function by function, batched, and refuses degenerate input."""

import numpy as np
import pytest
import torch

from lerobot_actionflow import geometry as G
from lerobot_actionflow import rotations as R
from lerobot_actionflow.geometry import se3 as G_se3


@pytest.fixture
def rotations():
    torch.manual_seed(0)
    return G.random_rotation(64, dtype=torch.float64)


def test_rotation_6d_round_trip_matches_geometry(rotations):
    r = rotations.numpy()
    ref6 = G.matrix_to_rotation_6d(rotations).numpy()
    np.testing.assert_allclose(R.matrix_to_rotation_6d(r), ref6, atol=1e-12)
    d6 = G.matrix_to_rotation_6d(rotations) + 0.1 * torch.randn(64, 6, dtype=torch.float64)
    ref = G.rotation_6d_to_matrix(d6).numpy()
    np.testing.assert_allclose(R.rotation_6d_to_matrix(d6.numpy()), ref, atol=1e-10)
    # batched over any leading shape, and one at a time
    np.testing.assert_allclose(R.rotation_6d_to_matrix(d6.numpy().reshape(8, 8, 6)), ref.reshape(8, 8, 3, 3))
    np.testing.assert_allclose(R.rotation_6d_to_matrix(d6[5].numpy()), ref[5], atol=1e-10)


def test_quaternions_match_geometry(rotations):
    q = R.matrix_to_quaternion(rotations.numpy())
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(q, G.matrix_to_quaternion(rotations).numpy(), atol=1e-9)
    np.testing.assert_allclose(R.quaternion_to_matrix(q), rotations.numpy(), atol=1e-9)
    np.testing.assert_allclose(R.quaternion_to_matrix(3.0 * q[0]), rotations[0].numpy(), atol=1e-9)
    np.testing.assert_allclose(R.wxyz_to_xyzw(q), G.wxyz_to_xyzw(torch.from_numpy(q)).numpy())
    np.testing.assert_allclose(R.xyzw_to_wxyz(R.wxyz_to_xyzw(q)), q)


def test_axis_angle_matches_geometry_exp_log(rotations):
    v = G.log(rotations)
    np.testing.assert_allclose(R.matrix_to_axis_angle(rotations.numpy()), v.numpy(), atol=1e-8)
    np.testing.assert_allclose(R.axis_angle_to_matrix(v.numpy()), G.exp(v).numpy(), atol=1e-9)
    np.testing.assert_allclose(
        R.geodesic_distance(rotations.numpy()[:-1], rotations.numpy()[1:]),
        G.geodesic_distance(rotations[:-1], rotations[1:]).numpy(),
        atol=1e-8,
    )


def test_yaw_matrix_is_a_rotation_about_z():
    yaws = np.linspace(-np.pi, np.pi, 7)
    ref = R.axis_angle_to_matrix(yaws[:, None] * [0.0, 0.0, 1.0])
    np.testing.assert_allclose(R.yaw_matrix(yaws), ref, atol=1e-12)


def test_rigid_transforms_match_geometry(rotations):
    torch.manual_seed(1)
    p = torch.randn(64, 3, dtype=torch.float64)
    r1, p1, r2, p2 = rotations[:32], p[:32], rotations[32:], p[32:]
    for ours, ref in (
        (R.compose(r1.numpy(), p1.numpy(), r2.numpy(), p2.numpy()), G_se3.compose(r1, p1, r2, p2)),
        (R.inverse(r1.numpy(), p1.numpy()), G_se3.inverse(r1, p1)),
    ):
        for a, b in zip(ours, ref, strict=True):
            np.testing.assert_allclose(a, b.numpy(), atol=1e-12)
    moved = R.apply(r1.numpy(), p1.numpy(), p2.numpy())
    np.testing.assert_allclose(moved, G_se3.apply(r1, p1, p2).numpy(), atol=1e-12)
    pose7 = R.rp_to_pose7(rotations.numpy(), p.numpy())
    np.testing.assert_allclose(pose7, G_se3.rp_to_pose7(rotations, p).numpy(), atol=1e-9)
    pose9 = R.rp_to_pose9(rotations.numpy(), p.numpy())
    np.testing.assert_allclose(pose9, G_se3.rp_to_pose9(rotations, p).numpy(), atol=1e-12)
    for back in (R.pose7_to_rp(pose7), R.pose9_to_rp(pose9)):
        np.testing.assert_allclose(back[0], rotations.numpy(), atol=1e-9)
        np.testing.assert_allclose(back[1], p.numpy(), atol=1e-12)


def test_rotation_order_matters():
    """Control: composing in the other order gives another transform, so the checks above can fail."""
    r1, r2 = R.yaw_matrix(0.3), R.axis_angle_to_matrix(np.array([0.4, 0.0, 0.0]))
    p1, p2 = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    assert not np.allclose(R.compose(r1, p1, r2, p2)[1], R.compose(r2, p2, r1, p1)[1])


@pytest.mark.parametrize(
    "d6",
    [np.zeros(6), np.array([1.0, 0, 0, 2.0, 0, 0]), np.array([0, 0, 0, 0, 1.0, 0])],
    ids=["zero", "parallel", "zero-first"],
)
def test_degenerate_rot6d_raises(d6):
    with pytest.raises(ValueError, match="6D rotation"):
        R.rotation_6d_to_matrix(d6)


@pytest.mark.parametrize("q", [np.zeros(4), np.array([np.nan, 0.0, 0.0, 1.0])], ids=["zero", "nan"])
def test_degenerate_quaternion_raises(q):
    with pytest.raises(ValueError, match="quaternion"):
        R.quaternion_to_matrix(q)


@pytest.mark.parametrize("scale", [1e-3, 1e155, 1e300])
def test_rotation_6d_is_scale_free_up_to_the_float_range(scale, rotations):
    """Huge columns would overflow the squared norms (a zero matrix, a 180 deg command)."""
    d6 = R.matrix_to_rotation_6d(rotations.numpy()[:4])
    for x in (d6, d6[0]):
        np.testing.assert_allclose(R.rotation_6d_to_matrix(scale * x), R.rotation_6d_to_matrix(x), atol=1e-12)
