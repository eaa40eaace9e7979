"""StackThree expert: pick cube A, place it on B, pick C, place it on A.

Each cube is grasped top-down at one of its four headings and placed so that its centre lands
the sum of the two half sizes (:data:`~lerobot_actionflow.envs.stack_three.CUBE_HALF_SIZES`)
above the centre of the cube below.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lerobot_actionflow.envs.stack_three import CUBE_HALF_SIZES
from lerobot_actionflow.envs.tabletop import TABLE_TOP_Z
from lerobot_actionflow.experts.base import Waypoint
from lerobot_actionflow.experts.pick_place import PickPlaceExpert
from lerobot_actionflow.experts.skills import (
    Grasp,
    PickDraws,
    PickParams,
    PlaceDraws,
    PlaceParams,
)

PICK_A = PickParams(order=4, grasp_dz=0.0, descend_speed=(0.08, 0.14))
PLACE_A = PlaceParams(carry_z=TABLE_TOP_Z + 0.15, lower_speed=(0.07, 0.12))
#: C is approached from over the tower of A on B (a low diagonal approach can knock A off);
#: ``avoid`` is set per episode (the tower's row).
PICK_C = PickParams(order=4, grasp_dz=0.0, approach_z=TABLE_TOP_Z + 0.16, descend_speed=(0.10, 0.16))
PLACE_C = PlaceParams(carry_z=TABLE_TOP_Z + 0.19, lower_speed=(0.07, 0.12))


@dataclass(frozen=True)
class StackThreeDraws:
    """The random choices of a StackThree episode (after the tempo), in the order of the fields."""

    pick_a: PickDraws
    place_a: PlaceDraws
    pick_c: PickDraws
    place_c: PlaceDraws

    @classmethod
    def draw(cls, rng: np.random.Generator, tempo: float) -> StackThreeDraws:
        return cls(
            pick_a=PickDraws.draw(rng, PICK_A, tempo),
            place_a=PlaceDraws.draw(rng, PLACE_A, tempo),
            pick_c=PickDraws.draw(rng, PICK_C, tempo),
            place_c=PlaceDraws.draw(rng, PLACE_C, tempo),
        )


class StackThreeExpert(PickPlaceExpert):
    """StackThree: A on B, then C on A. C is grasped with the hand across the direction to the
    tower when it lies within 0.2 m of it (the 0.2 m long hand sweeps A off B otherwise)."""

    version = "stack_three-3"
    tasks = ("StackThree_D0", "StackThree_D1", "StackThree_D2")

    def task_plan(self, rng: np.random.Generator) -> list[Waypoint]:
        d = StackThreeDraws.draw(rng, self.tempo)
        self.a, self.c = Grasp(self.entity_row("cubeA")), Grasp(self.entity_row("cubeC"))
        self.b_row = self.entity_row("cubeB")
        pick_c = replace(PICK_C, avoid=self.tower_xyz)
        return [
            *self.pick(self.a, PICK_A, d.pick_a),
            *self.place(self.a, self.on_b, PLACE_A, d.place_a),
            *self.pick(self.c, pick_c, d.pick_c),
            *self.place(self.c, self.on_a, PLACE_C, d.place_c),
        ]

    def tower_xyz(self, obs: dict) -> np.ndarray:
        return self.object_xyz(obs, self.b_row)

    def on_b(self, obs: dict) -> np.ndarray:
        """A's goal: centred on B."""
        return self.object_xyz(obs, self.b_row) + np.array(
            [0.0, 0.0, CUBE_HALF_SIZES["cubeB"] + CUBE_HALF_SIZES["cubeA"]]
        )

    def on_a(self, obs: dict) -> np.ndarray:
        """C's goal: centred on A."""
        return self.object_xyz(obs, self.a.row) + np.array(
            [0.0, 0.0, CUBE_HALF_SIZES["cubeA"] + CUBE_HALF_SIZES["cubeC"]]
        )
