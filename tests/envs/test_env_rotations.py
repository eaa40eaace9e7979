"""The numpy hot-path rotation helpers agree with the torch geometry package."""

import numpy as np
import pytest
import torch

from lerobot_actionflow import geometry as G
from lerobot_actionflow.envs import rotations as rot


@pytest.fixture
def rotations():
    torch.manual_seed(0)
    return G.random_rotation(64, dtype=torch.float64)


def test_matrix_to_rot6d_matches_geometry(rotations):
    np.testing.assert_allclose(
        rot.matrix_to_rot6d(rotations.numpy()), G.matrix_to_rotation_6d(rotations).numpy(), atol=1e-12
    )


def test_rot6d_to_matrix_matches_geometry(rotations):
    d6 = G.matrix_to_rotation_6d(rotations) + 0.1 * torch.randn(64, 6, dtype=torch.float64)
    ref = G.rotation_6d_to_matrix(d6).numpy()
    for i in range(64):
        np.testing.assert_allclose(rot.rot6d_to_matrix(d6[i].numpy()), ref[i], atol=1e-10)


def test_quaternion_round_trip_matches_geometry(rotations):
    for r in rotations:
        q = rot.matrix_to_quat(r.numpy())
        ref = G.matrix_to_quaternion(r).numpy()
        assert q[0] >= 0
        np.testing.assert_allclose(q, ref, atol=1e-9)
        np.testing.assert_allclose(
            rot.quat_to_matrix(q), G.quaternion_to_matrix(torch.from_numpy(q)), atol=1e-9
        )


def test_rotvec_matches_geometry_log(rotations):
    for r in rotations:
        np.testing.assert_allclose(rot.matrix_to_rotvec(r.numpy()), G.log(r).numpy(), atol=1e-8)


@pytest.mark.parametrize(
    "d6",
    [np.zeros(6), np.array([1.0, 0, 0, 2.0, 0, 0]), np.array([0, 0, 0, 0, 1.0, 0])],
    ids=["zero", "parallel", "zero-first"],
)
def test_degenerate_rot6d_raises(d6):
    with pytest.raises(ValueError, match="6D rotation"):
        rot.rot6d_to_matrix(d6)
