"""Smoothness of a commanded target trajectory (absolute EEF targets, one per control step).

For targets ``a_0 .. a_{T-1}``, rows ``[x, y, z, rot6d, gripper]`` (world frame):

* position jump ``|p_{t+1} - p_t|`` (m) and rotation jump ``angle(R_t^T R_{t+1})`` (rad, the
  geodesic distance on SO(3), :func:`lerobot_actionflow.rotations.geodesic_distance`), between
  consecutive steps; an episode's figure is the largest;
* jerk: the mean over ``t`` of ``|p_{t+3} - 3 p_{t+2} + 3 p_{t+1} - p_t|^2`` (m^2), the squared
  third finite difference of the commanded positions per control step (divide by ``dt^6`` for
  (m/s^3)^2).

Figures that need more steps than the trajectory has are 0 (no motion measured).
"""

from __future__ import annotations

import numpy as np

from lerobot_actionflow.rotations import geodesic_distance, rotation_6d_to_matrix
from lerobot_actionflow.schema import ACTION_DIM, POSE9_DIM

#: Keys of :func:`smoothness_figures`.
FIGURES = ("max_position_jump_m", "max_rotation_jump_rad", "jerk_m2")


def _check(targets: np.ndarray) -> np.ndarray:
    t = np.asarray(targets, dtype=np.float64)
    if t.ndim != 2 or t.shape[1] != ACTION_DIM:
        raise ValueError(f"targets must be (T, {ACTION_DIM}) [x y z rot6d gripper], got shape {t.shape}")
    return t


def position_jumps(targets: np.ndarray) -> np.ndarray:
    """``|p_{t+1} - p_t|`` (m) ``(T - 1,)``."""
    p = _check(targets)[:, :3]
    return np.linalg.norm(np.diff(p, axis=0), axis=-1)


def rotation_jumps(targets: np.ndarray) -> np.ndarray:
    """Geodesic angle between consecutive commanded rotations (rad) ``(T - 1,)``."""
    t = _check(targets)
    if len(t) < 2:
        return np.zeros(0)
    r = rotation_6d_to_matrix(t[:, 3:POSE9_DIM])
    return geodesic_distance(r[:-1], r[1:])


def jerk(targets: np.ndarray) -> float:
    """Mean squared third difference of the commanded positions (m^2); 0 below 4 steps."""
    p = _check(targets)[:, :3]
    if len(p) < 4:
        return 0.0
    return float(np.mean(np.sum(np.diff(p, n=3, axis=0) ** 2, axis=-1)))


def smoothness_figures(targets: np.ndarray) -> dict[str, float]:
    """The episode's largest position and rotation jumps and its jerk (:data:`FIGURES`)."""
    pos, rot = position_jumps(targets), rotation_jumps(targets)
    return {
        "max_position_jump_m": float(pos.max()) if len(pos) else 0.0,
        "max_rotation_jump_rad": float(rot.max()) if len(rot) else 0.0,
        "jerk_m2": jerk(targets),
    }
