"""Small numpy rotation helpers for the per-step hot path of the envs.

They mirror :mod:`lerobot_actionflow.geometry` (the torch reference, which the tests compare
against) with the same conventions: quaternions are scalar-first ``(w, x, y, z)``, the 6D
rotation is the first two columns of the rotation matrix ``(r00, r10, r20, r01, r11, r21)``.
They exist because a step of the env must cost microseconds, and a round trip through torch
for one pose costs more than the rest of the observation.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

#: Smallest norm accepted for either 3-vector of a 6D rotation, and smallest norm of the second
#: one after removing its component along the first (a parallel pair is no rotation).
ROT6D_EPS = 1e-6


def matrix_to_rot6d(r: np.ndarray) -> np.ndarray:
    """First two columns of ``(..., 3, 3)`` rotations, concatenated: ``(..., 6)``."""
    return np.concatenate((r[..., :, 0], r[..., :, 1]), axis=-1)


def rot6d_to_matrix(d6) -> np.ndarray:
    """Gram-Schmidt of one 6D rotation ``(6,) -> (3, 3)`` (scalar code: one call costs a few us).

    Raises:
        ValueError: if either vector is (nearly) zero or the two are (nearly) parallel.
    """
    ax, ay, az, bx, by, bz = (float(v) for v in d6[:6])
    n1 = math.sqrt(ax * ax + ay * ay + az * az)
    if n1 < ROT6D_EPS:
        raise ValueError(f"6D rotation has a (near) zero first column {[ax, ay, az]}")
    ax, ay, az = ax / n1, ay / n1, az / n1
    dot = ax * bx + ay * by + az * bz
    bx, by, bz = bx - dot * ax, by - dot * ay, bz - dot * az
    n2 = math.sqrt(bx * bx + by * by + bz * bz)
    if n2 < ROT6D_EPS:
        raise ValueError(f"6D rotation columns are (nearly) parallel or zero: {[float(v) for v in d6[:6]]}")
    bx, by, bz = bx / n2, by / n2, bz / n2
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    return np.array([[ax, bx, cx], [ay, by, cy], [az, bz, cz]])


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Scalar-first unit quaternion of one rotation matrix ``(3, 3) -> (4,)``, with ``w >= 0``."""
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(r, dtype=np.float64).reshape(9))
    if q[0] < 0:
        q *= -1.0
    return q


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of one scalar-first quaternion ``(4,) -> (3, 3)`` (normalised first)."""
    qn = np.asarray(q, dtype=np.float64)
    qn = qn / np.linalg.norm(qn)
    m = np.empty(9)
    mujoco.mju_quat2Mat(m, qn)
    return m.reshape(3, 3)


def matrix_to_rotvec(r: np.ndarray) -> np.ndarray:
    """Axis-angle vector ``axis * angle`` (angle in ``[0, pi]``) of one rotation ``(3, 3) -> (3,)``.

    This is the orientation format of robosuite's OSC controller in absolute mode
    (``scipy.spatial.transform.Rotation.from_rotvec``).
    """
    q = matrix_to_quat(r)
    v = np.empty(3)
    mujoco.mju_quat2Vel(v, q, 1.0)
    return v


def yaw_matrix(yaw: float) -> np.ndarray:
    """Rotation by ``yaw`` radians about the world z-axis."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
