"""Numpy rigid-body helpers for the scripted experts (one pose at a time, microseconds each).

Conventions as everywhere in the project: quaternions scalar-first ``(w, x, y, z)``, 6D
rotation = first two columns of the rotation matrix, poses in the world frame.
A pose is a pair ``(p (3,), R (3, 3))``; ``T = (p, R)`` maps a point ``x`` in its frame to
``R x + p`` in the world.
"""

from __future__ import annotations

import math

import numpy as np

from lerobot_actionflow.envs import rotations as rot

#: Top-down grasp orientation at yaw 0: EEF x along world +y, EEF y along world +x, EEF z
#: (the approach axis) pointing down. This is the Panda's home orientation in robosuite; the
#: fingers close along the EEF x axis (measured: in the grip-site frame the finger pads sit at
#: x = +-0.02..0.028 m and the hand spans x +-0.10 m, y +-0.032 m, 0.031-0.123 m behind the site).
R_DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def rz(yaw: float) -> np.ndarray:
    """Rotation by ``yaw`` about world z."""
    return rot.yaw_matrix(yaw)


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues: ``exp(hat(w))`` for an axis-angle vector ``w (3,)``."""
    th = float(np.linalg.norm(w))
    if th < 1e-12:
        return np.eye(3)
    k = w / th
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(th) * kx + (1.0 - math.cos(th)) * kx @ kx


def so3_log(r: np.ndarray) -> np.ndarray:
    """Axis-angle vector (angle in ``[0, pi]``) of a rotation matrix."""
    return rot.matrix_to_rotvec(r)


def angle_between(r1: np.ndarray, r2: np.ndarray) -> float:
    """Geodesic distance ``|Log(r1^T r2)|`` in radians."""
    c = (np.trace(r1.T @ r2) - 1.0) / 2.0
    return float(math.acos(min(1.0, max(-1.0, c))))


def pose_from_row(row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[x y z qw qx qy qz]`` -> ``(p (3,), R (3, 3))``."""
    return np.asarray(row[:3], dtype=np.float64).copy(), rot.quat_to_matrix(row[3:7])


def compose(a: tuple, b: tuple) -> tuple[np.ndarray, np.ndarray]:
    """``a * b``: ``(R_a p_b + p_a, R_a R_b)``."""
    return a[1] @ b[0] + a[0], a[1] @ b[1]


def inverse(a: tuple) -> tuple[np.ndarray, np.ndarray]:
    """``a^-1 = (-R^T p, R^T)``."""
    return -a[1].T @ a[0], a[1].T


def yaw_of(r: np.ndarray) -> float:
    """Heading of a rotation's x axis in the world xy plane."""
    return math.atan2(r[1, 0], r[0, 0])


def wrap(a: float) -> float:
    """Angle wrapped to ``(-pi, pi]``."""
    return math.pi - (math.pi - a) % (2 * math.pi)


def top_down(yaw: float, lean: float = 0.0) -> np.ndarray:
    """Top-down EEF orientation turned by ``yaw`` about world z from :data:`R_DOWN`, then
    tilted by ``lean`` about its own x axis (the fingers' closing axis): ``Rz(yaw) R_DOWN
    Rx(lean)``. The tilt keeps both finger pads at one height; it moves the wrist, which sits
    ``L`` behind the grip site along the approach axis, by ``L sin(lean)`` along the EEF y axis
    (``(cos yaw, sin yaw, 0)``)."""
    r = rz(yaw) @ R_DOWN
    return r if lean == 0.0 else r @ so3_exp(np.array([lean, 0.0, 0.0]))


#: Reachable headings ``psi`` (rad, relative to the home heading) of a top-down Panda grasp:
#: turning the other way than ``+`` drives wrist joint 7 into its limit beyond about -0.6 pi
#: (measured with robosuite 1.5.2's Panda, absolute OSC; +0.8 pi is still fine).
TURN_RANGE = (-0.5 * math.pi, 0.8 * math.pi)


def symmetric_yaws(
    obj_yaw: float, order: int, home: float, current: float, turn_range: tuple[float, float] = TURN_RANGE
) -> list[float]:
    """Grasp headings ``obj_yaw + 2 pi k / order`` reachable from the arm's home heading.

    An object with an ``order``-fold symmetry about z (4 for a cube) can be grasped from each of
    those headings. Kept: those with ``wrap(psi - home)`` in ``turn_range`` and less than
    ``0.9 pi`` from ``current`` (the commanded rotation takes the geodesic, which must not cross
    the unreachable side). Each is returned as ``home + wrap(psi - home)``; if none qualifies,
    the one closest to ``current``.
    """
    lo, hi = turn_range
    cands = [home + wrap(obj_yaw + 2 * math.pi * k / order - home) for k in range(order)]
    out = [c for c in cands if lo <= c - home <= hi and abs(wrap(c - current)) < 0.9 * math.pi]
    return out or [min(cands, key=lambda c: abs(wrap(c - current)))]


def action_from_pose(p: np.ndarray, r: np.ndarray, gripper: float) -> np.ndarray:
    """``(p, R, g)`` -> the env's float32 action ``[x y z rot6d g]`` (10,)."""
    return np.concatenate([p, r[:, 0], r[:, 1], [gripper]]).astype(np.float32)
