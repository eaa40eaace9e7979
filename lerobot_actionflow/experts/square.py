"""Square expert: grasp the nut's handle across its width (two headings), carry the nut over
the peg with its square hole turned to one of the peg's four alignments, lower it onto the peg
top, release (it slides down), retreat."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from lerobot_actionflow.experts import frames as fr
from lerobot_actionflow.experts.base import Waypoint
from lerobot_actionflow.experts.pick_place import PickPlaceExpert
from lerobot_actionflow.experts.pose import token_pose
from lerobot_actionflow.experts.skills import (
    Grasp,
    PickDraws,
    PickParams,
    PlaceDraws,
    PlaceParams,
    aligned_eef_rotation,
)

#: Handle centre on the nut's x axis, and the peg's half height (m), from robosuite's
#: NutAssemblySquare models (the task is robosuite's; our env modules do not define them).
HANDLE_X = 0.054
PEG_HALF_HEIGHT = 0.1
#: The handle (``grasp_offset``) is drawn per episode (:class:`SquareDraws`).
PICK = PickParams(order=2, grasp_dz=0.0, yaw_offset=math.pi / 2)
PLACE = PlaceParams(hover=(0.04, 0.07), release_dz=(0.0, 0.005), carry_z=1.05)


@dataclass(frozen=True)
class SquareDraws:
    """The random choices of a Square episode (after the tempo), in the order of the fields."""

    handle_x: float  # grasp point on the nut's x axis: HANDLE_X +- 8 mm
    above_peg: float  # release height of the nut's origin over the peg top (m)
    choice: float  # which admissible alignment turn, in [0, 1)
    pick: PickDraws
    place: PlaceDraws

    @classmethod
    def draw(cls, rng: np.random.Generator, tempo: float) -> SquareDraws:
        return cls(
            handle_x=HANDLE_X + float(rng.uniform(-0.008, 0.008)),
            above_peg=float(rng.uniform(0.015, 0.03)),
            choice=float(rng.random()),
            pick=PickDraws.draw(rng, PICK, tempo),
            place=PlaceDraws.draw(rng, PLACE, tempo),
        )


class SquareExpert(PickPlaceExpert):
    """Square: pick the nut by its handle, put it over the peg, aligned; :attr:`nut` holds the
    grasp."""

    version = "square-1"
    tasks = ("Square",)

    def task_plan(self, rng: np.random.Generator) -> list[Waypoint]:
        self.draws = d = SquareDraws.draw(rng, self.tempo)
        self.nut, self.peg_row = Grasp(self.entity_row("nut")), self.entity_row("peg")
        return [
            *self.pick(self.nut, replace(PICK, grasp_offset=(d.handle_x, 0.0)), d.pick),
            *self.place(self.nut, self.over_peg, PLACE, d.place, rot=self.aligned),
        ]

    def over_peg(self, obs: dict) -> np.ndarray:
        return self.object_xyz(obs, self.peg_row) + np.array(
            [0.0, 0.0, PEG_HALF_HEIGHT + self.draws.above_peg]
        )

    def aligned(self, obs: dict) -> np.ndarray:
        """The held nut turned so that its square hole lines up with the peg (order 4),
        preferring the turns that leave the handle (nut ``+x``) not pointing away from the robot
        (the arm's reach ends just beyond the peg)."""
        peg_yaw = fr.yaw_of(token_pose(obs, self.peg_row).r)
        home = self.home_heading(obs)
        return aligned_eef_rotation(
            self.nut, home, peg_yaw, 4, self.draws.choice, prefer=lambda yaw: math.cos(yaw) < 0.3
        )
