"""Unit quaternions and axis-angle, converted to and from rotation matrices.

Convention (the whole project's): quaternions are scalar-first, ``q = (w, x, y, z)``, like
MuJoCo. robosuite reports scalar-last ``(x, y, z, w)``; convert with :func:`xyzw_to_wxyz`
and :func:`wxyz_to_xyzw` once, at the environment boundary.

``q`` and ``-q`` are the same rotation; :func:`matrix_to_quaternion` returns the
representative with ``w >= 0``.
"""

from __future__ import annotations

import torch

from lerobot_actionflow.geometry import so3


def wxyz_to_xyzw(q: torch.Tensor) -> torch.Tensor:
    """Scalar-first ``(..., 4)`` to scalar-last (robosuite's order)."""
    _check_quat_shape(q)
    return torch.cat((q[..., 1:], q[..., :1]), -1)


def xyzw_to_wxyz(q: torch.Tensor) -> torch.Tensor:
    """Scalar-last ``(..., 4)`` (robosuite's order) to scalar-first."""
    _check_quat_shape(q)
    return torch.cat((q[..., 3:], q[..., :3]), -1)


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrix of a scalar-first quaternion ``(..., 4) -> (..., 3, 3)``.

    The quaternion is normalised first, so any non-zero ``q`` is accepted.
    """
    _check_quat_shape(q)
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return torch.stack(
        (
            torch.stack((1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)), -1),
            torch.stack((2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)), -1),
            torch.stack((2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)), -1),
        ),
        -2,
    )


def matrix_to_quaternion(r: torch.Tensor) -> torch.Tensor:
    """Scalar-first unit quaternion with ``w >= 0`` of a rotation ``(..., 3, 3) -> (..., 4)``.

    Shepperd's method: each of the four components can be read off the matrix, with
    ``4 q_i^2 = 1 + (signed trace combination)``; the largest is computed from the diagonal
    and the other three from off-diagonal sums divided by it, so nothing divides by a small
    number.
    """
    if r.ndim < 2 or r.shape[-2:] != (3, 3):
        raise ValueError(f"matrix_to_quaternion expects (..., 3, 3), got shape {tuple(r.shape)}")
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    m01, m02, m10 = r[..., 0, 1], r[..., 0, 2], r[..., 1, 0]
    m12, m20, m21 = r[..., 1, 2], r[..., 2, 0], r[..., 2, 1]
    # 4 q_i^2 for i = w, x, y, z.
    four_sq = torch.stack(
        (1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22), -1
    )
    tiny = torch.finfo(r.dtype).tiny
    # Candidate k has component k equal to sqrt(four_sq_k)/2 and the others from off-diagonals.
    two_q = torch.sqrt(four_sq.clamp_min(tiny))  # 2 |q_k|
    candidates = torch.stack(
        (
            torch.stack((two_q[..., 0] ** 2, m21 - m12, m02 - m20, m10 - m01), -1),
            torch.stack((m21 - m12, two_q[..., 1] ** 2, m10 + m01, m02 + m20), -1),
            torch.stack((m02 - m20, m10 + m01, two_q[..., 2] ** 2, m12 + m21), -1),
            torch.stack((m10 - m01, m20 + m02, m21 + m12, two_q[..., 3] ** 2), -1),
        ),
        -2,
    ) / (2 * two_q[..., :, None])
    best = four_sq.argmax(-1)
    q = torch.gather(candidates, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def quaternion_multiply(q1: torch.Tensor, q2: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``q1 * q2`` (scalar-first), the quaternion of ``R(q1) @ R(q2)``."""
    _check_quat_shape(q1)
    _check_quat_shape(q2)
    w1, x1, y1, z1 = q1.unbind(-1)
    w2, x2, y2, z2 = q2.unbind(-1)
    return torch.stack(
        (
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ),
        -1,
    )


def axis_angle_to_matrix(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotation by ``angle`` (radians, ``(...)``) about ``axis`` (``(..., 3)``, any length > 0)."""
    axis = axis / torch.linalg.vector_norm(axis, dim=-1, keepdim=True)
    return so3.exp(axis * torch.as_tensor(angle, dtype=axis.dtype, device=axis.device)[..., None])


def matrix_to_axis_angle(r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit axis ``(..., 3)`` and angle in ``[0, pi]`` ``(...)``; the axis is ``(1, 0, 0)`` at
    the identity, where any axis is valid."""
    w = so3.log(r)
    angle = torch.linalg.vector_norm(w, dim=-1)
    default = torch.zeros_like(w)
    default[..., 0] = 1
    axis = torch.where(
        (angle > 0)[..., None], w / angle.clamp_min(torch.finfo(w.dtype).tiny)[..., None], default
    )
    return axis, angle


def _check_quat_shape(q: torch.Tensor) -> None:
    if q.shape[-1] != 4:
        raise ValueError(f"expected quaternions (..., 4), got shape {tuple(q.shape)}")
