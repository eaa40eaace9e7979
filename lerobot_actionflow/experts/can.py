"""Can expert: a top-down grasp of the upright can at any heading (it is round), carried over
the target bin at a safe height, lowered into its cell, released."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lerobot_actionflow.experts.base import Waypoint
from lerobot_actionflow.experts.pick_place import PickPlaceExpert
from lerobot_actionflow.experts.skills import (
    Grasp,
    PickDraws,
    PickParams,
    PlaceDraws,
    PlaceParams,
)

#: ``grasp_dz`` is drawn per episode (:class:`CanDraws`).
PICK = PickParams(order=0, grasp_dz=0.0)
PLACE = PlaceParams(hover=(0.08, 0.12), release_dz=(0.0, 0.01), carry_z=1.02)


@dataclass(frozen=True)
class CanDraws:
    """The random choices of a Can episode (after the tempo), in the order of the fields."""

    drop: float  # release height of the can's bottom over the cell (m)
    #: ``(2,)`` xy of the aim point from the cell's centre (m), towards the robot: the cell
    #: (about 0.10 x 0.12 m) sits at the edge of the Panda's reach.
    cell: np.ndarray
    grasp_dz: float  # grasp height over the can's origin (m)
    pick: PickDraws
    place: PlaceDraws

    @classmethod
    def draw(cls, rng: np.random.Generator, tempo: float) -> CanDraws:
        drop = float(rng.uniform(0.01, 0.025))
        cell = rng.uniform(-0.04, -0.015, 2)
        grasp_dz = float(rng.uniform(0.0, 0.015))
        pick = PickDraws.draw(rng, replace(PICK, grasp_dz=grasp_dz), tempo)
        return cls(drop, cell, grasp_dz, pick, PlaceDraws.draw(rng, PLACE, tempo))


class CanExpert(PickPlaceExpert):
    """Can: pick the can, place it in its bin's cell; :attr:`can` holds the grasp."""

    version = "can-1"
    tasks = ("Can",)

    def task_plan(self, rng: np.random.Generator) -> list[Waypoint]:
        self.draws = d = CanDraws.draw(rng, self.tempo)
        self.can, self.goal_row = Grasp(self.entity_row("can")), self.entity_row("goal")
        rs = self.env.robosuite_env
        self.bottom = -float(rs.objects[rs.object_id].bottom_offset[2])  # can origin over its bottom
        return [
            *self.pick(self.can, replace(PICK, grasp_dz=d.grasp_dz), d.pick),
            *self.place(self.can, self.in_cell, PLACE, d.place),
        ]

    def in_cell(self, obs: dict) -> np.ndarray:
        d = self.draws
        return self.object_xyz(obs, self.goal_row) + np.array([d.cell[0], d.cell[1], self.bottom + d.drop])
