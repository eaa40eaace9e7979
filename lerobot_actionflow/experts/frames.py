"""Frames of a top-down Panda grasp, grasp headings, and the env action built from a pose.

Angles are in radians. A grasp heading ``psi`` names the top-down EEF orientation
``top_down(psi) = Rz(psi) R_DOWN``; since ``R_DOWN``'s x axis is world ``+y``, the EEF x axis
(the fingers' closing axis) has the world yaw ``psi + pi / 2`` (:func:`heading` inverts this).
The rotation maths is :mod:`lerobot_actionflow.rotations`.
"""

from __future__ import annotations

import math

import numpy as np

from lerobot_actionflow import rotations
from lerobot_actionflow.experts.pose import Pose

#: Top-down grasp orientation at heading 0: EEF x along world +y, EEF y along world +x, EEF z
#: (the approach axis) pointing down. This is the Panda's home orientation in robosuite; the
#: fingers close along the EEF x axis (measured: in the grip-site frame the finger pads sit at
#: x = +-0.02..0.028 m and the hand spans x +-0.10 m, y +-0.032 m, 0.031-0.123 m behind the site).
R_DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

#: Reachable headings ``psi`` (relative to the home heading) of a top-down Panda grasp: turning
#: the other way than ``+`` drives wrist joint 7 into its limit beyond about -0.6 pi (measured
#: with robosuite 1.5.2's Panda, absolute OSC; +0.8 pi is still fine).
TURN_RANGE = (-0.5 * math.pi, 0.8 * math.pi)


def yaw_of(r: np.ndarray) -> float:
    """World yaw of a rotation's x axis: ``atan2(r10, r00)``."""
    return math.atan2(r[1, 0], r[0, 0])


def heading(r: np.ndarray) -> float:
    """Grasp heading ``psi`` of a top-down orientation ``r = top_down(psi)``: ``yaw_of(r) - pi / 2``."""
    return yaw_of(r) - math.pi / 2


def wrap(a: float) -> float:
    """Angle wrapped to ``(-pi, pi]``."""
    return math.pi - (math.pi - a) % (2 * math.pi)


def top_down(psi: float, lean: float = 0.0) -> np.ndarray:
    """Top-down EEF orientation turned by ``psi`` about world z from :data:`R_DOWN`, then tilted
    by ``lean`` about its own x axis (the fingers' closing axis): ``Rz(psi) R_DOWN Rx(lean)``.

    The tilt keeps both finger pads at one height; it moves the wrist, which sits ``L`` behind
    the grip site along the approach axis, by ``L sin(lean)`` along the EEF y axis
    ``(cos psi, sin psi, 0)``."""
    r = rotations.yaw_matrix(psi) @ R_DOWN
    return r if lean == 0.0 else r @ rotations.axis_angle_to_matrix(np.array([lean, 0.0, 0.0]))


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


def across(headings: list[float], d: np.ndarray) -> list[float]:
    """The headings whose finger axis (world yaw ``psi + pi / 2``) lies most nearly across the
    horizontal direction ``d`` (``(2,)`` or more): those with ``|cos|`` of the angle between the
    two within 0.1 of the smallest."""
    h = math.atan2(d[1], d[0])
    score = [abs(math.cos(y + math.pi / 2 - h)) for y in headings]
    return [y for y, c in zip(headings, score, strict=True) if c <= min(score) + 0.1]


def pick_one(options: list, choice: float):
    """``options[floor(choice * n)]`` for ``choice`` in ``[0, 1)`` (a uniform draw made earlier)."""
    return options[min(int(choice * len(options)), len(options) - 1)]


def action(pose: Pose, gripper: float) -> np.ndarray:
    """The env's float32 action ``[pose9 (9), gripper]`` ``(10,)`` (schema ``action``): the
    absolute world EEF target ``[x, y, z, rot6d]`` and the gripper command (-1 open, +1 closed)."""
    return np.concatenate((rotations.rp_to_pose9(pose.r, pose.p), [gripper])).astype(np.float32)
