"""Scene transform: one planar rigid motion applied to a task's whole initial layout.

At every reset, after the task has sampled its initial placement, a transform
``g = (yaw, tx, ty)`` is drawn (each a constant or a uniform range) and applied to every free
object and every fixture of the task (:attr:`TaskSpec.fixtures`):

    p' = Rz(yaw) (p - c) + c + (tx, ty, 0),    R' = Rz(yaw) R,

where ``c`` is the task's pivot (:attr:`TaskSpec.pivot_xy`, the centre of the placement region,
at the height of the point). With ``move_robot=True`` the arm's initial end-effector pose is
moved by the same ``g`` (solved by inverse kinematics on the arm joints, without simulating
physics), so the whole initial state - robot included - is the transformed one and an
SE(3)-equivariant policy should behave identically; with ``move_robot=False`` only the objects
move, which tests generalisation to layouts unseen relative to the robot.

Valid range (checked when the transform is made): ``|tx|, |ty| <= 0.10`` m; any yaw in
``[-pi, pi]`` for the objects; ``|yaw| <= pi/2`` with ``move_robot=True`` (the Panda's wrist
joint limits and reach do not allow more everywhere). At each reset the env also checks that
every entity stays over the table (2 cm margin): a transform with ranges is redrawn until it
does (the layout distribution is conditioned on it), a constant one that does not raises
``ValueError``. Layouts within 0.28 m of the pivot (all D0/D1 variants and the robomimic tasks)
never leave the 0.8 m table; D2 variants may need smaller shifts. Tasks whose goal is a fixed
part of the arena (Can's bins) do not support a transform.

This module holds the transform's parameters only (importing it is cheap);
:mod:`lerobot_actionflow.envs.scene_mover` applies it to a MuJoCo scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Largest |tx|, |ty| in metres.
MAX_SHIFT = 0.10
#: Largest |yaw| in radians when the robot is moved too.
MAX_ROBOT_YAW = math.pi / 2

Range = float | tuple[float, float]


def _as_range(value: Range, name: str) -> tuple[float, float]:
    if isinstance(value, int | float):
        lo = hi = float(value)
    else:
        vals = tuple(float(v) for v in value)
        if len(vals) != 2:
            raise ValueError(f"scene transform {name} must be a number or a (low, high) pair, got {value!r}")
        lo, hi = vals
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
        raise ValueError(f"scene transform {name} range must be finite with low <= high, got {value!r}")
    return lo, hi


@dataclass(frozen=True)
class SceneTransform:
    """A planar rigid transform of the initial layout; each part a constant or a ``(low, high)``
    range sampled uniformly at every reset. See the module docstring for its meaning and range."""

    yaw: Range = 0.0
    x: Range = 0.0
    y: Range = 0.0
    move_robot: bool = False

    def __post_init__(self):
        if not isinstance(self.move_robot, bool | np.bool_):  # "false" would be truthy
            raise TypeError(f"scene transform move_robot must be a bool, got {self.move_robot!r}")
        ylo, yhi = _as_range(self.yaw, "yaw")
        max_yaw = MAX_ROBOT_YAW if self.move_robot else math.pi
        if ylo < -max_yaw - 1e-9 or yhi > max_yaw + 1e-9:
            raise ValueError(
                f"scene transform yaw {self.yaw!r} outside [-{max_yaw!r}, {max_yaw!r}] "
                f"(move_robot={self.move_robot})"
            )
        for name in ("x", "y"):
            lo, hi = _as_range(getattr(self, name), name)
            if lo < -MAX_SHIFT - 1e-9 or hi > MAX_SHIFT + 1e-9:
                raise ValueError(f"scene transform {name} {getattr(self, name)!r} outside +-{MAX_SHIFT} m")

    @classmethod
    def coerce(cls, value: SceneTransform | dict | None) -> SceneTransform | None:
        """Accept a transform, a dict of its fields (as gym kwargs carry it), or None."""
        if value is None or isinstance(value, SceneTransform):
            return value
        if isinstance(value, dict):
            return cls(**value)
        raise TypeError(f"scene_transform must be a SceneTransform, a dict or None, got {type(value)}")

    @property
    def is_identity(self) -> bool:
        return all(_as_range(getattr(self, n), n) == (0.0, 0.0) for n in ("yaw", "x", "y"))

    def sample(self, rng: np.random.Generator) -> tuple[float, float, float]:
        """Draw ``(yaw, tx, ty)``; constants are returned without consuming randomness."""
        out = []
        for name in ("yaw", "x", "y"):
            lo, hi = _as_range(getattr(self, name), name)
            out.append(lo if lo == hi else float(rng.uniform(lo, hi)))
        return out[0], out[1], out[2]
