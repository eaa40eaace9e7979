"""ThreePieceAssembly expert: piece 1 into the base's socket, then piece 2 into piece 1's.

Each piece is picked top-down (four headings), turned square to its socket
(:func:`~lerobot_actionflow.experts.skills.aligned_eef_rotation`), lowered in and released.
A piece far from the robot is first set down nearer (:mod:`.relocate`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_actionflow.envs.tabletop import TABLE_TOP_Z
from lerobot_actionflow.envs.three_piece_assembly import PIECE1_OVER_BASE, PIECE2_OVER_PIECE1
from lerobot_actionflow.experts import frames as fr
from lerobot_actionflow.experts.base import Waypoint
from lerobot_actionflow.experts.pick_place import PickPlaceExpert
from lerobot_actionflow.experts.pose import token_pose
from lerobot_actionflow.experts.relocate import Relocate, RelocateDraws, Relocation, lean_pick
from lerobot_actionflow.experts.skills import (
    Grasp,
    PickDraws,
    PickParams,
    Place,
    PlaceDraws,
    PlaceParams,
    aligned_eef_rotation,
)

PICK1 = PickParams(order=4, grasp_dz=-0.005, xy_noise=0.002)
PICK2 = PickParams(order=4, grasp_dz=0.0, xy_noise=0.002)
#: A place's descent ends after 45 steps: a piece not seated by then is jammed on the socket's
#: rim, and waiting does not free it (releasing it often does); a relocation costs about 100 of
#: the 500 steps.
PLACE1 = PlaceParams(
    hover=(0.03, 0.06), release_dz=(0.0, 0.002), carry_z=TABLE_TOP_Z + 0.15, lower_timeout=45
)
PLACE2 = PlaceParams(
    hover=(0.03, 0.06), release_dz=(0.0, 0.002), carry_z=TABLE_TOP_Z + 0.17, lower_timeout=45
)


@dataclass(frozen=True)
class ThreePieceAssemblyDraws:
    """The random choices of an episode (after the tempo), in the order of the fields."""

    choice1: float  # which admissible alignment turn of piece 1, in [0, 1)
    choice2: float  # of piece 2
    extra1: float  # release height of piece 1 over its inserted height (m)
    extra2: float  # of piece 2
    relocate1: RelocateDraws
    pick1: PickDraws
    place1: PlaceDraws
    relocate2: RelocateDraws
    pick2: PickDraws
    place2: PlaceDraws

    @classmethod
    def draw(cls, rng: np.random.Generator, tempo: float) -> ThreePieceAssemblyDraws:
        return cls(
            choice1=float(rng.random()),
            choice2=float(rng.random()),
            extra1=float(rng.uniform(0.002, 0.006)),
            extra2=float(rng.uniform(0.002, 0.006)),
            relocate1=RelocateDraws.draw(rng, lean_pick(PICK1.order, PICK1.grasp_dz), tempo),
            pick1=PickDraws.draw(rng, PICK1, tempo),
            place1=PlaceDraws.draw(rng, PLACE1, tempo),
            relocate2=RelocateDraws.draw(rng, lean_pick(PICK2.order, PICK2.grasp_dz), tempo),
            pick2=PickDraws.draw(rng, PICK2, tempo),
            place2=PlaceDraws.draw(rng, PLACE2, tempo),
        )


class ThreePieceAssemblyExpert(PickPlaceExpert):
    """ThreePieceAssembly: (relocate,) pick, align and insert piece 1, then piece 2.
    :attr:`piece1` / :attr:`piece2` hold the grasps, :attr:`relocation1` / :attr:`relocation2`
    the relocations."""

    version = "three_piece_assembly-2"
    tasks = ("ThreePieceAssembly_D0", "ThreePieceAssembly_D1", "ThreePieceAssembly_D2")

    def task_plan(self, rng: np.random.Generator) -> list[Waypoint]:
        self.draws = d = ThreePieceAssemblyDraws.draw(rng, self.tempo)
        self.base_row = self.entity_row("base")
        self.piece1, self.piece2 = Grasp(self.entity_row("piece1")), Grasp(self.entity_row("piece2"))
        self.relocation1 = Relocation(self.piece1.row, others=(self.base_row, self.piece2.row))
        self.relocation2 = Relocation(self.piece2.row, others=(self.base_row,))
        lean1, lean2 = lean_pick(PICK1.order, PICK1.grasp_dz), lean_pick(PICK2.order, PICK2.grasp_dz)
        place1 = Place(self.piece1, self.into_base, PLACE1, d.place1, rot=self.align1)
        place2 = Place(self.piece2, self.into_piece1, PLACE2, d.place2, rot=self.align2)
        return [
            *Relocate(self, self.relocation1, lean1, d.relocate1).waypoints(),
            *self.pick(self.piece1, PICK1, d.pick1),
            *place1.waypoints(),
            *Relocate(self, self.relocation2, lean2, d.relocate2).waypoints(),
            *self.pick(self.piece2, PICK2, d.pick2),
            *place2.waypoints(),
        ]

    def into_base(self, obs: dict) -> np.ndarray:
        return self.object_xyz(obs, self.base_row) + np.array(
            [0.0, 0.0, PIECE1_OVER_BASE + self.draws.extra1]
        )

    def into_piece1(self, obs: dict) -> np.ndarray:
        return self.object_xyz(obs, self.piece1.row) + np.array(
            [0.0, 0.0, PIECE2_OVER_PIECE1 + self.draws.extra2]
        )

    def align1(self, obs: dict) -> np.ndarray:
        """Piece 1 square to the base's socket."""
        ref = fr.yaw_of(token_pose(obs, self.base_row).r)
        return aligned_eef_rotation(self.piece1, self.home_heading(obs), ref, 4, self.draws.choice1)

    def align2(self, obs: dict) -> np.ndarray:
        """Piece 2 square to piece 1's socket."""
        ref = fr.yaw_of(token_pose(obs, self.piece1.row).r)
        return aligned_eef_rotation(self.piece2, self.home_heading(obs), ref, 4, self.draws.choice2)
