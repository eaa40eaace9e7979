"""ThreePieceAssembly: insert piece 1 into the base's socket, then piece 2 into piece 1's.

Objects (robosuite ``CompositeObject`` s of boxes, free joints; sizes are full extents):

- **base** (``assembly_base``): a 0.12 x 0.12 x 0.01 m plate carrying a square socket, four
  0.02 m high walls around a 0.052 x 0.052 m opening; heavy, so it stays put.
- **piece 1** (``piece1``): a 0.048 x 0.048 x 0.03 m block (fits the base's socket with 2 mm
  clearance per side) with its own square socket on top (walls 0.015 m high around a
  0.042 x 0.042 m opening).
- **piece 2** (``piece2``): a 0.038 x 0.038 x 0.03 m block (fits piece 1's socket with 2 mm per side).

Success: piece 1 within 0.02 m (xy) of the base and at its inserted height (within 5 mm), not
grasped; piece 2 within 0.02 m (xy) of piece 1 and at its inserted height on it (within
5 mm), not grasped. Inserting a piece needs its yaw aligned with the socket's (modulo 90 deg)
to within a few degrees.

Placement variants (yaw in degrees; pieces on either side of the base, ranges relative to
the table centre):

| variant | base x, y / yaw   | piece 1 x, y / yaw             | piece 2 x, y / yaw            |
| ------- | ----------------- | ------------------------------ | ----------------------------- |
| D0      | +-0.02 / 0        | +-0.08, [-0.22, -0.15] / +-15  | +-0.08, [0.15, 0.22] / +-15   |
| D1      | +-0.08 / +-45     | +-0.12, [-0.25, -0.15] / +-90  | +-0.12, [0.15, 0.25] / +-90   |
| D2      | +-0.22 / +-45     | +-0.22, +-0.22 / [0, 180]      | +-0.22, +-0.22 / [0, 180]     |

D2 follows the ranges Mimicgen documents for ThreePieceAssembly_D2; D0 and D1 are ours.
Placements never overlap (robosuite's rejection sampling).
"""

from __future__ import annotations

import math

import numpy as np

from lerobot_actionflow.envs.materials import box_composite, textured
from lerobot_actionflow.envs.tabletop import Placement, TabletopTask

_D = math.radians
ASSEMBLY_VARIANTS: dict[str, dict[str, Placement]] = {
    "D0": {
        "base": Placement(x=(-0.02, 0.02), y=(-0.02, 0.02), yaw=(0.0, 0.0)),
        "piece1": Placement(x=(-0.08, 0.08), y=(-0.22, -0.15), yaw=(-_D(15), _D(15))),
        "piece2": Placement(x=(-0.08, 0.08), y=(0.15, 0.22), yaw=(-_D(15), _D(15))),
    },
    "D1": {
        "base": Placement(x=(-0.08, 0.08), y=(-0.08, 0.08), yaw=(-_D(45), _D(45))),
        "piece1": Placement(x=(-0.12, 0.12), y=(-0.25, -0.15), yaw=(-_D(90), _D(90))),
        "piece2": Placement(x=(-0.12, 0.12), y=(0.15, 0.25), yaw=(-_D(90), _D(90))),
    },
    "D2": {
        "base": Placement(x=(-0.22, 0.22), y=(-0.22, 0.22), yaw=(-_D(45), _D(45))),
        "piece1": Placement(x=(-0.22, 0.22), y=(-0.22, 0.22), yaw=(0.0, math.pi)),
        "piece2": Placement(x=(-0.22, 0.22), y=(-0.22, 0.22), yaw=(0.0, math.pi)),
    },
}

#: Height of piece 1's body origin over the base's, and of piece 2's over piece 1's, when inserted.
PIECE1_OVER_BASE = 0.0175
PIECE2_OVER_PIECE1 = 0.0225
XY_TOLERANCE = 0.02
Z_TOLERANCE = 0.005


def _socket_walls(inner: float, thick: float, height: float, z: float) -> tuple[list, list]:
    """Sizes and locations of four walls around a square opening of half width ``inner``."""
    c = inner + thick / 2
    sizes = [(thick / 2, inner + thick, height / 2)] * 2 + [(inner, thick / 2, height / 2)] * 2
    locs = [(c, 0.0, z), (-c, 0.0, z), (0.0, c, z), (0.0, -c, z)]
    return sizes, locs


def make_base(name: str = "assembly_base"):
    half = (0.06, 0.06, 0.015)
    w_sizes, w_locs = _socket_walls(inner=0.026, thick=0.006, height=0.02, z=0.005)
    return box_composite(
        name,
        materials=[textured("WoodDark", f"{name}_wood")],
        geom_materials=[0] * 5,
        total_size=half,
        geom_types=["box"] * 5,
        geom_sizes=[(0.06, 0.06, 0.005), *w_sizes],
        geom_locations=[(0.0, 0.0, -0.01), *w_locs],
        geom_names=["plate", "wall0", "wall1", "wall2", "wall3"],
        density=5000.0,
        locations_relative_to_center=True,
    )


def make_piece1(name: str = "piece1"):
    w_sizes, w_locs = _socket_walls(inner=0.021, thick=0.003, height=0.015, z=0.015)
    return box_composite(
        name,
        materials=[textured("WoodRed", f"{name}_wood")],
        geom_materials=[0] * 5,
        total_size=(0.024, 0.024, 0.0225),
        geom_types=["box"] * 5,
        geom_sizes=[(0.024, 0.024, 0.015), *w_sizes],
        geom_locations=[(0.0, 0.0, -0.0075), *w_locs],
        geom_names=["block", "wall0", "wall1", "wall2", "wall3"],
        density=500.0,
        locations_relative_to_center=True,
    )


def make_piece2(name: str = "piece2"):
    return box_composite(
        name,
        materials=[textured("WoodBlue", f"{name}_wood")],
        geom_materials=[0],
        total_size=(0.019, 0.019, 0.015),
        geom_types=["box"],
        geom_sizes=[(0.019, 0.019, 0.015)],
        geom_locations=[(0.0, 0.0, 0.0)],
        geom_names=["block"],
        density=500.0,
        locations_relative_to_center=True,
    )


class ThreePieceAssembly(TabletopTask):
    """Assemble base, piece 1 and piece 2; ``variant`` in ``"D0"``, ``"D1"``, ``"D2"``."""

    VARIANTS = tuple(ASSEMBLY_VARIANTS)

    def _build_objects(self):
        place = ASSEMBLY_VARIANTS[self.variant]
        return {
            "base": (make_base(), place["base"]),
            "piece1": (make_piece1(), place["piece1"]),
            "piece2": (make_piece2(), place["piece2"]),
        }

    def _inserted(self, piece: str, into: str, height: float) -> bool:
        p, q = self.body_pos(piece), self.body_pos(into)
        return (
            bool(np.linalg.norm(p[:2] - q[:2]) < XY_TOLERANCE)
            and abs(p[2] - q[2] - height) < Z_TOLERANCE
            and not self.grasped(piece)
        )

    def _check_success(self) -> bool:
        return self._inserted("piece1", "base", PIECE1_OVER_BASE) and self._inserted(
            "piece2", "piece1", PIECE2_OVER_PIECE1
        )


def subgoals(env: ThreePieceAssembly) -> dict[str, bool]:
    """Piece 1 grasped, inserted into the base, piece 2 grasped, inserted into piece 1."""
    return {
        "piece1_grasped": env.grasped("piece1"),
        "piece1_inserted": env._inserted("piece1", "base", PIECE1_OVER_BASE),
        "piece2_grasped": env.grasped("piece2"),
        "piece2_inserted": env._inserted("piece2", "piece1", PIECE2_OVER_PIECE1),
    }
