"""The settings of the point-cloud observation (:mod:`lerobot_actionflow.envs.point_cloud`).

This module holds the parameters only (importing it is cheap: no MuJoCo, no robosuite), so that
the envs package and the LeRobot env config can validate them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_actionflow.schema import DEFAULT_POINT_CLOUD_POINTS


@dataclass(frozen=True)
class PointCloudConfig:
    """How the env makes ``observation["point_cloud"]``.

    Attributes:
        num_points: ``M``, the rows of the cloud.
        cameras: two or more depth cameras (aliases as in
            :data:`~lerobot_actionflow.envs.rendering.CAMERA_ALIASES`, or model camera names);
            ``None`` (or empty) for the task's :attr:`TaskSpec.point_cloud_cameras`.
        image_height, image_width: depth image size per camera (more pixels: denser, slower).
        box_low, box_high: the workspace crop box in the world frame (metres); ``None`` for the
            task's action workspace box.
        seed: seed of the first farthest-point index (the same state gives the same cloud).
    """

    num_points: int = DEFAULT_POINT_CLOUD_POINTS
    cameras: tuple[str, ...] | None = None
    image_height: int = 128
    image_width: int = 128
    box_low: tuple[float, float, float] | None = None
    box_high: tuple[float, float, float] | None = None
    seed: int = 0

    def __post_init__(self):
        cams = self.cameras.split(",") if isinstance(self.cameras, str) else (self.cameras or ())
        cams = tuple(c.strip() for c in cams if c.strip())
        object.__setattr__(self, "cameras", cams or None)
        if self.cameras is not None and len(self.cameras) < 2:
            raise ValueError(f"point_cloud needs two or more cameras, got {list(self.cameras)}")
        if int(self.num_points) < 1:
            raise ValueError(f"point_cloud num_points must be >= 1, got {self.num_points}")
        if min(int(self.image_height), int(self.image_width)) < 1:
            raise ValueError(
                f"point_cloud image size must be >= 1 pixel, got {(self.image_height, self.image_width)}"
            )
        if (self.box_low is None) != (self.box_high is None):
            raise ValueError("point_cloud box_low and box_high must be given together")
        if self.box_low is not None:
            low, high = np.asarray(self.box_low, float), np.asarray(self.box_high, float)
            if low.shape != (3,) or high.shape != (3,) or not (low < high).all():
                raise ValueError(
                    "point_cloud box must be two (3,) corners with low < high, "
                    f"got {self.box_low}, {self.box_high}"
                )

    @classmethod
    def coerce(cls, value: PointCloudConfig | dict | bool | None) -> PointCloudConfig | None:
        """Accept a config, a dict of its fields (as gym kwargs carry it), ``True`` (defaults),
        or ``False`` / ``None`` (no point cloud)."""
        if value is None or value is False:
            return None
        if value is True:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, dict):
            return cls(**value)
        raise TypeError(f"point_cloud must be a bool, a dict or a PointCloudConfig, got {type(value)}")
