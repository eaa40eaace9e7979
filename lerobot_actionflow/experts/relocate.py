"""Relocation: set an object that lies out of a top-down hand's reach down nearer the robot.

Far from the robot a top-down hand straightens the Panda's arm into a pose it cannot leave. A
relocation picks such an object with the hand leaning towards the robot (:class:`PickParams`
``lean``, about the fingers' closing axis) and sets it down nearer, where the ordinary top-down
pick takes it: a leaning pinch does not hold a piece level enough for an insertion, but setting
it down on the table needs no precision.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lerobot_actionflow.envs.tabletop import TABLE_TOP_Z
from lerobot_actionflow.experts.base import Waypoint
from lerobot_actionflow.experts.pick_place import PickPlaceExpert
from lerobot_actionflow.experts.skills import (
    Grasp,
    Pick,
    PickDraws,
    PickParams,
    Place,
    PlaceDraws,
    PlaceParams,
)

#: An object at least this far (m, horizontally) from the robot base is relocated before its
#: pick. Lowered from 0.95 m straight down, as a pick does, the top-down hand reaches 0.77 m
#: (elbow -0.75 rad) but stops 2 cm short of 0.80 m, with the arm straightened against its
#: elbow limit (:data:`.skills.LEAN_START`).
RELOCATE_FROM = 0.74
#: Relocation moves run this many times the episode's tempo (they need no precision, and the
#: episode's time limit is shared with the task).
TEMPO_FACTOR = 1.3
#: Set-down: distance range (m) from the robot base; turn step (rad) about the base while
#: looking for a free spot, and the clearance (m) it needs from the other entities.
SPOT_RANGE = (0.62, 0.66)
SPOT_TURN = 0.12
SPOT_CLEARANCE = 0.13
#: Where a relocated object is set down: carried low, 5-7 cm up.
PLACE = PlaceParams(
    hover=(0.02, 0.04),
    release_dz=(0.0, 0.002),
    carry_z=TABLE_TOP_Z + 0.07,
    lower_speed=(0.1, 0.16),
    up=(0.04, 0.06),
)


def lean_pick(order: int, grasp_dz: float) -> PickParams:
    """The leaning pick of a relocation."""
    return PickParams(order=order, grasp_dz=grasp_dz, xy_noise=0.002, lean=True, lift_range=(0.05, 0.07))


@dataclass(frozen=True)
class RelocateDraws:
    """The random choices of one relocation, drawn in the order of the fields (the pick's and
    the place's at :data:`TEMPO_FACTOR` times the tempo)."""

    spot_radius: float  # distance of the set-down spot from the robot base (m)
    drop: float  # set-down height over the object's height where it lay (m)
    pick: PickDraws
    place: PlaceDraws

    @classmethod
    def draw(cls, rng: np.random.Generator, pick: PickParams, tempo: float) -> RelocateDraws:
        return cls(
            spot_radius=float(rng.uniform(*SPOT_RANGE)),
            drop=float(rng.uniform(0.002, 0.006)),
            pick=PickDraws.draw(rng, pick, TEMPO_FACTOR * tempo),
            place=PlaceDraws.draw(rng, PLACE, TEMPO_FACTOR * tempo),
        )


@dataclass
class Relocation:
    """One object's relocation, decided when its waypoints are reached.

    Attributes:
        row: the object's row in ``obs["poses"]``.
        others: rows of the entities the set-down spot must keep clear of.
        grasp: the leaning grasp that carries it.
        far: whether it lay :data:`RELOCATE_FROM` or further from the robot base (``None``:
            not decided yet).
        spot: world position ``(3,)`` where it is set down (when ``far``).
    """

    row: int
    others: tuple[int, ...]
    grasp: Grasp = field(init=False)
    far: bool | None = None
    spot: np.ndarray | None = None

    def __post_init__(self):
        self.grasp = Grasp(self.row)


class Relocate:
    """If the object lies :data:`RELOCATE_FROM` or further from the robot base when these
    waypoints are reached, pick it with a leaning hand, carry it low and set it down on the
    table :data:`SPOT_RANGE` from the base, on the line from the base through it, turned about
    the base (steps of :data:`SPOT_TURN`) until it is :data:`SPOT_CLEARANCE` or more from the
    other entities; otherwise the waypoints are skipped. The object keeps its yaw."""

    def __init__(
        self, expert: PickPlaceExpert, relocation: Relocation, pick: PickParams, draws: RelocateDraws
    ):
        self.expert, self.relocation, self.draws = expert, relocation, draws
        self.pick = Pick(expert, relocation.grasp, pick, draws.pick)
        self.place = Place(relocation.grasp, self.spot, PLACE, draws.place)

    def waypoints(self) -> list[Waypoint]:
        return [*self.pick.waypoints(when=self.far), *self.place.waypoints(when=self.far)]

    def far(self, obs: dict) -> bool:
        """Decides (once) whether the object is relocated, and where to."""
        rel = self.relocation
        if rel.far is None:
            p = self.expert.object_xyz(obs, rel.row)
            rel.far = self.expert.reach(p) >= RELOCATE_FROM
            if rel.far:
                rel.spot = np.array([*self.clear_spot(obs, p), p[2] + self.draws.drop])
        return rel.far

    def spot(self, obs: dict) -> np.ndarray:
        return self.relocation.spot

    def clear_spot(self, obs: dict, p: np.ndarray) -> np.ndarray:
        """World xy ``(2,)`` of the set-down spot for an object at ``p``."""
        base = self.expert.robot_base_xy()
        r = self.draws.spot_radius
        a0 = math.atan2(p[1] - base[1], p[0] - base[0])
        spots = [
            base + r * np.array([math.cos(a0 + SPOT_TURN * k), math.sin(a0 + SPOT_TURN * k)])
            for k in range(-4, 5)
        ]
        spots.sort(key=lambda q: float(np.linalg.norm(q - p[:2])))
        for q in spots:
            if all(
                float(np.linalg.norm(q - self.expert.object_xyz(obs, o)[:2])) >= SPOT_CLEARANCE
                for o in self.relocation.others
            ):
                return q
        return spots[0]
