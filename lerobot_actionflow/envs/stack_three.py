"""StackThree: stack three cubes into one tower, built from robosuite primitives.

Scene: robosuite's ``TableArena`` (0.8 x 0.8 m table, top at z = 0.8 m), a Panda at the table's
edge, and three ``BoxObject`` cubes with free joints:

- cube A, red, half size 0.02 m;
- cube B, green, half size 0.025 m (the base of the tower);
- cube C, blue, half size 0.02 m.

Success: A on B and C on A. "X on Y" means X's centre is above the table top by more than a
margin (0.04 m for A, 0.08 m for C, so C must be on the tower, not leaning on its side), X
touches Y, and X is not grasped by the gripper.

Placement variants (``variant``), the cubes sampled one after another without overlap,
relative to the table centre, yaw about z uniform in the range:

| variant | x range (m)    | y range (m)    | yaw range      |
| ------- | -------------- | -------------- | -------------- |
| D0      | +-0.10         | +-0.10         | [-pi/4, pi/4]  |
| D1      | +-0.20         | +-0.20         | [0, 2 pi)      |
| D2      | [-0.25, 0.15]  | +-0.30         | [0, 2 pi)      |

D0/D1 follow Mimicgen's ranges as documented in DESIGN.md section 7; D2 is ours (Mimicgen has
no StackThree_D2): a wider y spread, cut in x so that every placement stays within the arm's reach.
"""

from __future__ import annotations

import math

from robosuite.models.objects import BoxObject

from lerobot_actionflow.envs.materials import textured
from lerobot_actionflow.envs.tabletop import TABLE_TOP_Z, Placement, TabletopTask

#: variant -> (x range, y range, yaw range), relative to the table top centre.
STACK_THREE_VARIANTS: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "D0": ((-0.10, 0.10), (-0.10, 0.10), (-math.pi / 4, math.pi / 4)),
    "D1": ((-0.20, 0.20), (-0.20, 0.20), (0.0, 2 * math.pi)),
    "D2": ((-0.25, 0.15), (-0.30, 0.30), (0.0, 2 * math.pi)),
}

#: Half sizes of cubes A, B, C.
CUBE_HALF_SIZES = {"cubeA": 0.02, "cubeB": 0.025, "cubeC": 0.02}
#: Height of a cube's centre over the table top above which it counts as lifted.
LIFT_MARGIN = {"cubeA": 0.04, "cubeC": 0.08}
_LOOKS = {
    "cubeA": ("WoodRed", [1, 0, 0, 1]),
    "cubeB": ("WoodGreen", [0, 1, 0, 1]),
    "cubeC": ("WoodBlue", [0, 0, 1, 1]),
}


class StackThree(TabletopTask):
    """Three cubes to stack (A on B, C on A); ``variant`` in ``"D0"``, ``"D1"``, ``"D2"``."""

    VARIANTS = tuple(STACK_THREE_VARIANTS)

    def _build_objects(self):
        x, y, yaw = STACK_THREE_VARIANTS[self.variant]
        built = {}
        for name, half in CUBE_HALF_SIZES.items():
            texture, rgba = _LOOKS[name]
            cube = BoxObject(
                name=name, size=[half] * 3, rgba=rgba, material=textured(texture, f"{name}_wood")
            )
            built[name] = (cube, Placement(x=x, y=y, yaw=yaw, z_offset=0.01))
        return built

    def _on(self, top: str, bottom: str) -> bool:
        """``top`` rests on ``bottom``: lifted over its margin, touching it, not grasped."""
        if self.body_pos(top)[2] - TABLE_TOP_Z <= LIFT_MARGIN[top]:
            return False
        if not self.check_contact(self.objects[top], self.objects[bottom]):
            return False
        return not self.grasped(top)

    def _check_success(self) -> bool:
        return self._on("cubeA", "cubeB") and self._on("cubeC", "cubeA")


def subgoals(env: StackThree) -> dict[str, bool]:
    """Cube A grasped, A on B, cube C grasped, C on A (with A on B: success)."""
    return {
        "cubeA_grasped": env.grasped("cubeA"),
        "cubeA_on_cubeB": env._on("cubeA", "cubeB"),
        "cubeC_grasped": env.grasped("cubeC"),
        "cubeC_on_cubeA": env._on("cubeC", "cubeA"),
    }
