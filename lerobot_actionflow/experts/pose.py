"""The experts' rigid pose: a named ``(r, p)`` pair on :mod:`lerobot_actionflow.rotations`.

A :class:`Pose` ``T = (r, p)`` (rotation ``(3, 3)`` first, translation ``(3,)`` second, as in
:mod:`lerobot_actionflow.rotations` and :mod:`lerobot_actionflow.geometry`) maps a point ``x``
of its frame to ``r x + p`` in the world frame. ``a @ b`` composes: ``(r_a r_b, r_a p_b + p_a)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_actionflow import rotations
from lerobot_actionflow.schema import ENV_POSES


@dataclass(frozen=True, eq=False)
class Pose:
    """A rigid transform ``x -> r x + p``.

    Attributes:
        r: rotation matrix ``(3, 3)``.
        p: translation ``(3,)`` (m).
    """

    r: np.ndarray
    p: np.ndarray

    @classmethod
    def from_pose7(cls, row: np.ndarray) -> Pose:
        """``[x, y, z, qw, qx, qy, qz]`` (a row of the env's ``poses``) -> ``Pose``."""
        r, p = rotations.pose7_to_rp(np.asarray(row)[:7])
        return cls(r, p)

    def __matmul__(self, other: Pose) -> Pose:
        """``self * other = (r_s r_o, r_s p_o + p_s)``."""
        return Pose(*rotations.compose(self.r, self.p, other.r, other.p))

    def inverse(self) -> Pose:
        """``T^-1 = (r^T, -r^T p)``."""
        return Pose(*rotations.inverse(self.r, self.p))

    def apply(self, x: np.ndarray) -> np.ndarray:
        """``T x = r x + p`` for a point ``x`` ``(3,)`` given in this pose's frame."""
        return self.p + self.r @ np.asarray(x, dtype=np.float64)

    def raised(self, dz: float) -> Pose:
        """The same orientation, the position moved by ``dz`` along world ``z``."""
        return Pose(self.r, self.p + np.array([0.0, 0.0, dz]))


def token_pose(obs: dict, row: int) -> Pose:
    """World pose of row ``row`` of ``obs["poses"]`` (row 0: the EEF, then the task's entities)."""
    return Pose.from_pose7(obs[ENV_POSES][row])
