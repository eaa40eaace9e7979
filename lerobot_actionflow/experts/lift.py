"""Lift expert: a top-down grasp of the cube at one of its four headings, then a lift."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_actionflow.experts.base import Waypoint
from lerobot_actionflow.experts.pick_place import PickPlaceExpert
from lerobot_actionflow.experts.skills import Grasp, PickDraws, PickParams

#: The cube, grasped at its centre from any of its four sides; lifted 0.10-0.16 m.
PICK = PickParams(order=4, grasp_dz=0.0)


@dataclass(frozen=True)
class LiftDraws:
    """The random choices of a Lift episode (after the tempo), in the order of the fields."""

    pick: PickDraws

    @classmethod
    def draw(cls, rng: np.random.Generator, tempo: float) -> LiftDraws:
        return cls(pick=PickDraws.draw(rng, PICK, tempo))


class LiftExpert(PickPlaceExpert):
    """Lift: pick the cube (:data:`PICK`) and lift it; :attr:`cube` holds the grasp."""

    version = "lift-1"
    tasks = ("Lift",)

    def task_plan(self, rng: np.random.Generator) -> list[Waypoint]:
        draws = LiftDraws.draw(rng, self.tempo)
        self.cube = Grasp(self.entity_row("cube"))
        return self.pick(self.cube, PICK, draws.pick)
