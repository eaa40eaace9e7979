"""Threading: push a needle's tip through the ring of a tripod, built from robosuite boxes.

Objects (robosuite ``CompositeObject`` s of boxes, free joints):

- **needle**: a handle (0.06 x 0.02 x 0.02 m) and a thin shaft (0.09 x 0.005 x 0.005 m) along
  the needle's local +x; its tip is the site ``needle_tip`` at the shaft's end, 0.075 m from the
  body origin.
- **tripod**: three feet lying on the table at 120 deg, a vertical post, and on top a ring of 16
  boxes in the tripod's local y-z plane (ring axis along local x), inner radius 0.012 m, outer
  0.022 m, centre (site ``tripod_ring_center``) 0.10 m above the table.

Success: the needle's tip is within the ring's inner radius (0.012 m) of the ring's centre
(3D distance), which the ring's walls allow only when the needle is threaded through it.

Placement variants: the needle on the -y side pointing roughly at +y, the tripod on the +y
side with its ring facing the needle (yaw pi/2 means both local x-axes point along +y):

| variant | needle x / y / yaw                     | tripod x / y / yaw                          |
| ------- | -------------------------------------- | ------------------------------------------- |
| D0      | +-0.05 / [-0.20, -0.15] / 90 +- 15 deg | +-0.05 / [0.10, 0.15] / 90 +- 15 deg        |
| D1      | +-0.10 / [-0.25, -0.15] / 90 +- 60 deg | +-0.10 / [0.10, 0.20] / 90 +- 45 deg        |
| D2      | +-0.15 / [-0.25, -0.15] / 90 +- 120 deg | [-0.15, 0.10] / [0.10, 0.20] / 90 +- 60 deg |

D2 matches the widths Mimicgen documents for Threading_D2 (needle yaw span 240 deg, tripod 120
deg, the same y bands); D0 and D1 are ours.
"""

from __future__ import annotations

import math

import numpy as np
from robosuite.models.objects import CompositeObject

from lerobot_actionflow.envs.materials import box_composite, textured
from lerobot_actionflow.envs.tabletop import Placement, TabletopTask
from lerobot_actionflow.rotations import axis_angle_to_matrix, matrix_to_quaternion

NEEDLE_TIP_X = 0.075
RING_INNER_RADIUS = 0.012
RING_OUTER_RADIUS = 0.022
RING_HEIGHT = 0.10
RING_SEGMENTS = 16

_D = math.radians
THREADING_VARIANTS: dict[str, dict[str, Placement]] = {
    "D0": {
        "needle": Placement(
            x=(-0.05, 0.05), y=(-0.20, -0.15), yaw=(math.pi / 2 - _D(15), math.pi / 2 + _D(15))
        ),
        "tripod": Placement(
            x=(-0.05, 0.05), y=(0.10, 0.15), yaw=(math.pi / 2 - _D(15), math.pi / 2 + _D(15))
        ),
    },
    "D1": {
        "needle": Placement(
            x=(-0.10, 0.10), y=(-0.25, -0.15), yaw=(math.pi / 2 - _D(60), math.pi / 2 + _D(60))
        ),
        "tripod": Placement(
            x=(-0.10, 0.10), y=(0.10, 0.20), yaw=(math.pi / 2 - _D(45), math.pi / 2 + _D(45))
        ),
    },
    "D2": {
        "needle": Placement(
            x=(-0.15, 0.15), y=(-0.25, -0.15), yaw=(math.pi / 2 - _D(120), math.pi / 2 + _D(120))
        ),
        "tripod": Placement(
            x=(-0.15, 0.10), y=(0.10, 0.20), yaw=(math.pi / 2 - _D(60), math.pi / 2 + _D(60))
        ),
    },
}


def _about(axis: str, angle: float) -> list[float]:
    """Scalar-first quaternion of a rotation by ``angle`` about the coordinate axis ``"x"``,
    ``"y"`` or ``"z"``."""
    return matrix_to_quaternion(axis_angle_to_matrix(angle * np.eye(3)["xyz".index(axis)])).tolist()


def make_needle(name: str = "needle") -> CompositeObject:
    half_handle = (0.03, 0.01, 0.01)
    half_shaft = (0.045, 0.0025, 0.0025)
    return box_composite(
        name,
        materials=[textured("WoodDark", f"{name}_handle"), textured("SteelBrushed", f"{name}_shaft")],
        geom_materials=[0, 1],
        total_size=(NEEDLE_TIP_X, 0.01, 0.01),
        geom_types=["box", "box"],
        geom_sizes=[half_handle, half_shaft],
        geom_locations=[(-0.045, 0.0, 0.0), (0.03, 0.0, 0.0)],
        geom_names=["handle", "shaft"],
        density=[800.0, 2000.0],
        locations_relative_to_center=True,
        sites=[{"name": "tip", "pos": (NEEDLE_TIP_X, 0, 0), "size": "0.002", "rgba": "1 0 0 1"}],
    )


def make_tripod(name: str = "tripod") -> CompositeObject:
    half_z = (RING_HEIGHT + RING_OUTER_RADIUS) / 2
    bottom = -half_z
    types, sizes, locs, quats, names = [], [], [], [], []
    for k, angle in enumerate((math.pi / 2, math.pi / 2 + 2 * math.pi / 3, math.pi / 2 + 4 * math.pi / 3)):
        types.append("box")
        sizes.append((0.045, 0.008, 0.006))
        locs.append((0.035 * math.cos(angle), 0.035 * math.sin(angle), bottom + 0.006))
        quats.append(_about("z", angle))
        names.append(f"foot{k}")
    post_h = RING_HEIGHT - RING_OUTER_RADIUS + 0.002
    types.append("box")
    sizes.append((0.006, 0.006, post_h / 2))
    locs.append((0.0, 0.0, bottom + post_h / 2))
    quats.append([1.0, 0.0, 0.0, 0.0])
    names.append("post")
    r_mid = (RING_INNER_RADIUS + RING_OUTER_RADIUS) / 2
    half_radial = (RING_OUTER_RADIUS - RING_INNER_RADIUS) / 2
    half_tangential = r_mid * math.tan(math.pi / RING_SEGMENTS) * 1.05
    for k in range(RING_SEGMENTS):
        theta = 2 * math.pi * k / RING_SEGMENTS
        types.append("box")
        # Local axes of a segment: x along the ring axis, y radial, z tangential.
        sizes.append((0.004, half_radial, half_tangential))
        locs.append((0.0, r_mid * math.cos(theta), bottom + RING_HEIGHT + r_mid * math.sin(theta)))
        quats.append(_about("x", theta))
        names.append(f"ring{k}")
    n = len(types)
    return box_composite(
        name,
        materials=[textured("WoodLight", f"{name}_wood")],
        geom_materials=[0] * n,
        total_size=(0.06, 0.06, half_z),
        geom_types=types,
        geom_sizes=sizes,
        geom_locations=locs,
        geom_quats=quats,
        geom_names=names,
        density=[20000.0] * 3 + [3000.0] * (n - 3),
        locations_relative_to_center=True,
        sites=[
            {
                "name": "ring_center",
                "pos": (0, 0, bottom + RING_HEIGHT),
                "size": "0.002",
                "rgba": "0 1 0 1",
            }
        ],
    )


class Threading(TabletopTask):
    """Thread the needle through the tripod's ring; ``variant`` in ``"D0"``, ``"D1"``, ``"D2"``."""

    VARIANTS = tuple(THREADING_VARIANTS)

    def _build_objects(self):
        place = THREADING_VARIANTS[self.variant]
        return {"needle": (make_needle(), place["needle"]), "tripod": (make_tripod(), place["tripod"])}

    def tip_to_ring_distance(self) -> float:
        return float(np.linalg.norm(self.site_pos("needle_tip") - self.site_pos("tripod_ring_center")))

    def _check_success(self) -> bool:
        return self.tip_to_ring_distance() < RING_INNER_RADIUS


def subgoals(env: Threading) -> dict[str, bool]:
    """Needle grasped, needle threaded (success)."""
    return {"needle_grasped": env.grasped("needle"), "threaded": env._check_success()}
