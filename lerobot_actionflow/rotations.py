"""Rotations and rigid poses in numpy, on :class:`scipy.spatial.transform.Rotation`.

The numpy counterpart of :mod:`lerobot_actionflow.geometry` (torch), with the same names,
argument orders and conventions, for the code that runs beside the simulator (envs, experts,
data conversion), which must not import torch:

* quaternions are scalar-first ``(w, x, y, z)`` and returned with ``w >= 0``;
* ``rot6d`` is the first two columns of the rotation matrix ``(r00, r10, r20, r01, r11, r21)``,
  mapped back by Gram-Schmidt;
* an axis-angle vector is ``axis * angle`` with the angle in ``[0, pi]`` (scipy's ``rotvec``,
  also the orientation format of robosuite's OSC controller);
* a rigid transform is the pair ``(r, p)``, rotation ``(..., 3, 3)`` first, translation
  ``(..., 3)`` second; it maps a point ``x`` to ``r x + p``. ``pose7 = [x, y, z, qw, qx, qy, qz]``
  and ``pose9 = [x, y, z, rot6d]`` are the schema's layouts (:mod:`lerobot_actionflow.schema`).

Every function broadcasts over leading dimensions and returns float64.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

#: Smallest norm accepted for either 3-vector of a 6D rotation, and smallest norm of the second
#: one after removing its component along the first (a parallel pair is no rotation).
ROT6D_EPS = 1e-6
#: Columns with an entry above this are rescaled before Gram-Schmidt (their squared norm would
#: overflow float64 beyond ~1e154).
ROT6D_RESCALE = 1e100


def _batched(fn, x: np.ndarray, tail: int, out_tail: tuple[int, ...]) -> np.ndarray:
    """Apply a scipy conversion ``(M, *in) -> (M, *out)`` to ``x`` with any leading shape."""
    x = np.asarray(x, dtype=np.float64)
    lead = x.shape[: x.ndim - tail]
    flat = x.reshape(-1, *x.shape[x.ndim - tail :])
    return np.asarray(fn(flat), dtype=np.float64).reshape(*lead, *out_tail)


# ------------------------------------------------------------------ quaternions
def xyzw_to_wxyz(q: np.ndarray) -> np.ndarray:
    """Scalar-last ``(..., 4)`` (robosuite) -> scalar-first."""
    q = np.asarray(q)
    return np.concatenate((q[..., 3:], q[..., :3]), axis=-1)


def wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    """Scalar-first ``(..., 4)`` -> scalar-last."""
    q = np.asarray(q)
    return np.concatenate((q[..., 1:], q[..., :1]), axis=-1)


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Scalar-first quaternions ``(..., 4)`` (normalised first) -> rotations ``(..., 3, 3)``.

    Raises:
        ValueError: for a zero or non-finite quaternion.
    """
    q = np.asarray(q, dtype=np.float64)
    if not np.isfinite(q).all():
        raise ValueError(f"quaternion has non-finite entries: {q[~np.isfinite(q).all(-1)][:3].tolist()}")
    return _batched(lambda x: Rotation.from_quat(x, scalar_first=True).as_matrix(), q, 1, (3, 3))


def matrix_to_quaternion(r: np.ndarray) -> np.ndarray:
    """Rotations ``(..., 3, 3)`` -> scalar-first unit quaternions ``(..., 4)`` with ``w >= 0``.

    The input must be a rotation matrix (it is not re-orthogonalised; that costs 4x more)."""

    def to_quat(x):
        return Rotation.from_matrix(x, assume_valid=True).as_quat(canonical=True, scalar_first=True)

    return _batched(to_quat, r, 2, (4,))


# ------------------------------------------------------------------ axis-angle
def axis_angle_to_matrix(v: np.ndarray) -> np.ndarray:
    """``Exp``: axis-angle vectors ``(..., 3)`` -> rotations ``(..., 3, 3)``."""
    return _batched(lambda x: Rotation.from_rotvec(x).as_matrix(), v, 1, (3, 3))


def matrix_to_axis_angle(r: np.ndarray) -> np.ndarray:
    """``Log``: rotations ``(..., 3, 3)`` -> axis-angle vectors ``(..., 3)``, angle in ``[0, pi]``.

    The input must be a rotation matrix (it is not re-orthogonalised)."""
    return _batched(lambda x: Rotation.from_matrix(x, assume_valid=True).as_rotvec(), r, 2, (3,))


def yaw_matrix(yaw) -> np.ndarray:
    """Rotation by ``yaw`` radians about the world z axis: ``(...) -> (..., 3, 3)``."""
    if np.ndim(yaw) == 0:  # the experts' per-step case, without the stacking overhead
        c, s = np.cos(yaw), np.sin(yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    yaw = np.asarray(yaw, dtype=np.float64)
    c, s, z, o = np.cos(yaw), np.sin(yaw), np.zeros_like(yaw), np.ones_like(yaw)
    return np.stack((np.stack((c, -s, z), -1), np.stack((s, c, z), -1), np.stack((z, z, o), -1)), -2)


def geodesic_distance(r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """Angle ``|Log(r1^T r2)|`` in ``[0, pi]`` between rotations ``(..., 3, 3)``."""
    return np.linalg.norm(matrix_to_axis_angle(np.swapaxes(r1, -1, -2) @ r2), axis=-1)


# ------------------------------------------------------------------ 6D rotations
def matrix_to_rotation_6d(r: np.ndarray) -> np.ndarray:
    """First two columns of rotations ``(..., 3, 3)``, concatenated: ``(..., 6)``."""
    r = np.asarray(r, dtype=np.float64)
    return np.concatenate((r[..., :, 0], r[..., :, 1]), axis=-1)


def rotation_6d_to_matrix(d6: np.ndarray) -> np.ndarray:
    """Gram-Schmidt of 6D rotations ``(..., 6) -> (..., 3, 3)``: ``b1 = a1 / |a1|``,
    ``b2 = (a2 - (b1.a2) b1) / |.|``, ``b3 = b1 x b2``, as columns. A column with an entry above
    :data:`ROT6D_RESCALE` is first divided by its largest absolute entry (the result is
    scale-free), so entries up to the float64 maximum do not overflow the norms; other columns are
    used as they are, so ordinary inputs round exactly as plain Gram-Schmidt. The (near-)zero
    tests apply to the unscaled norms.

    Raises:
        ValueError: if either vector is (nearly) zero or the two are (nearly) parallel.
    """
    d6 = np.asarray(d6, dtype=np.float64)
    if d6.shape == (6,):
        return _rotation_6d_to_matrix_one(d6)
    a1, a2 = d6[..., :3], d6[..., 3:6]
    m1 = np.abs(a1).max(axis=-1, keepdims=True)
    m2 = np.abs(a2).max(axis=-1, keepdims=True)
    m1, m2 = np.where(m1 > ROT6D_RESCALE, m1, 1.0), np.where(m2 > ROT6D_RESCALE, m2, 1.0)
    a1, a2 = a1 / m1, a2 / m2
    n1 = np.linalg.norm(a1, axis=-1, keepdims=True)
    if (n1 * m1 < ROT6D_EPS).any():
        raise ValueError(f"6D rotation has a (near) zero first column: {d6.tolist()}")
    b1 = a1 / n1
    a2 = a2 - (b1 * a2).sum(-1, keepdims=True) * b1
    n2 = np.linalg.norm(a2, axis=-1, keepdims=True)
    if (n2 * m2 < ROT6D_EPS).any():
        raise ValueError(f"6D rotation columns are (nearly) parallel or zero: {d6.tolist()}")
    b2 = a2 / n2
    (x1, y1, z1), (x2, y2, z2) = np.moveaxis(b1, -1, 0), np.moveaxis(b2, -1, 0)
    b3 = np.stack((y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2), axis=-1)  # b1 x b2
    return np.stack((b1, b2, b3), axis=-1)


def _rotation_6d_to_matrix_one(d6: np.ndarray) -> np.ndarray:
    """:func:`rotation_6d_to_matrix` of one ``(6,)`` vector in scalar arithmetic: the env converts
    one action per step, where the batched array code costs ~10x more (microseconds matter there)."""
    ax, ay, az, bx, by, bz = d6.tolist()
    m1, m2 = max(abs(ax), abs(ay), abs(az)), max(abs(bx), abs(by), abs(bz))
    m1, m2 = (m1 if m1 > ROT6D_RESCALE else 1.0), (m2 if m2 > ROT6D_RESCALE else 1.0)
    if m1 != 1.0:
        ax, ay, az = ax / m1, ay / m1, az / m1
    if m2 != 1.0:
        bx, by, bz = bx / m2, by / m2, bz / m2
    n1 = math.sqrt(ax * ax + ay * ay + az * az)
    if n1 * m1 < ROT6D_EPS:
        raise ValueError(f"6D rotation has a (near) zero first column: {d6.tolist()}")
    ax, ay, az = ax / n1, ay / n1, az / n1
    dot = ax * bx + ay * by + az * bz
    bx, by, bz = bx - dot * ax, by - dot * ay, bz - dot * az
    n2 = math.sqrt(bx * bx + by * by + bz * bz)
    if n2 * m2 < ROT6D_EPS:
        raise ValueError(f"6D rotation columns are (nearly) parallel or zero: {d6.tolist()}")
    bx, by, bz = bx / n2, by / n2, bz / n2
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    return np.array([[ax, bx, cx], [ay, by, cy], [az, bz, cz]])


# ------------------------------------------------------------------ rigid transforms (r, p)
def compose(r1: np.ndarray, p1: np.ndarray, r2: np.ndarray, p2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``T1 T2 = (r1 r2, r1 p2 + p1)``."""
    return r1 @ r2, (r1 @ p2[..., None])[..., 0] + p1


def inverse(r: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``T^-1 = (r^T, -r^T p)``."""
    rt = np.swapaxes(r, -1, -2)
    return rt, -(rt @ p[..., None])[..., 0]


def apply(r: np.ndarray, p: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``T x = r x + p`` for points ``x`` ``(..., 3)``."""
    return (r @ np.asarray(x)[..., None])[..., 0] + p


def pose7_to_rp(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[x, y, z, qw, qx, qy, qz]`` ``(..., 7)`` -> ``(r, p)``."""
    pose = np.asarray(pose, dtype=np.float64)
    return quaternion_to_matrix(pose[..., 3:7]), pose[..., :3].copy()


def rp_to_pose7(r: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``(r, p)`` -> ``[x, y, z, qw, qx, qy, qz]`` with ``qw >= 0``."""
    return np.concatenate((np.asarray(p, dtype=np.float64), matrix_to_quaternion(r)), axis=-1)


def pose9_to_rp(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[x, y, z, rot6d]`` ``(..., 9)`` -> ``(r, p)`` (Gram-Schmidt on the 6D part)."""
    pose = np.asarray(pose, dtype=np.float64)
    return rotation_6d_to_matrix(pose[..., 3:9]), pose[..., :3].copy()


def rp_to_pose9(r: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``(r, p)`` -> ``[x, y, z, rot6d]``."""
    return np.concatenate((np.asarray(p, dtype=np.float64), matrix_to_rotation_6d(r)), axis=-1)
