"""MugHang expert: pick the mug from above, turn its handle across the peg, slide the handle
down the peg, set it on the peg and let go.

Frames (:mod:`lerobot_actionflow.envs.mug_hang`): the hanger token is the peg's root ``a`` with
its x axis ``u`` along the peg (rising towards the tip); the handle's opening is centred at
``h = (HANDLE_X, 0, 0)`` in the mug frame, and its normal is the mug's y axis. The mug is
grasped top-down with the fingers closing along its y axis (two headings), so the opening's
normal stays horizontal and along the fingers.

For the hang the hand turns the mug about world z (:func:`~.skills.aligned_eef_rotation`, order
2) until its y axis lies along the peg's horizontal direction: the handle then points across the
peg, the body on its left or its right (whichever the wrist reaches, at random). Every target is
a position ``q`` of the opening's centre, turned into the EEF pose that puts it there with the
mug held per its grasp ``G``: ``T_mug = (R_m, q - R_m h)``, ``R_m = r G_r``, ``T_eef = T_mug
G^-1``. The centre goes to ``a + (L + standoff) u`` (in front of the tip, on the peg's axis),
slides along ``-u`` to ``a + depth u`` (the peg now through the opening; ``G`` is measured
again just before, as the mug may have swung in the fingers while carried), drops until the
handle's top bar rests on the peg, and the hand opens and rises: the mug swings down about the
peg and settles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import numpy as np

from lerobot_actionflow.envs.mug_hang import HANDLE_X, MUG_HALF_HEIGHT, PEG_LENGTH
from lerobot_actionflow.experts.base import Waypoint
from lerobot_actionflow.experts.pick_place import PickPlaceExpert
from lerobot_actionflow.experts.pose import Pose, token_pose
from lerobot_actionflow.experts.skills import Grasp, PickDraws, PickParams, aligned_eef_rotation, speed

#: The mug's body from above, fingers along its y axis (two headings), 2.5 cm below its rim (the
#: hand's palm stays clear of the rim).
PICK = PickParams(order=2, grasp_dz=MUG_HALF_HEIGHT - 0.025, xy_noise=0.002)
#: The opening's centre in the mug frame.
OPENING = np.array([HANDLE_X, 0.0, 0.0])


@dataclass(frozen=True)
class MugHangDraws:
    """The random choices of a MugHang episode (after the tempo), in the order of the fields."""

    choice: float  # which of the two mug headings across the peg, in [0, 1)
    standoff: float  # opening's centre beyond the peg's tip, along the peg, before the slide (m)
    hover: float  # carry height over the stand-off point (m)
    depth: float  # opening's centre along the peg from its root at the end of the slide (m)
    drop: float  # how far the opening's centre drops below the peg's axis to seat the handle (m)
    pick: PickDraws
    carry_speed: float
    align_speed: float
    align_hold: int
    insert_speed: float
    seat_speed: float
    release_hold: int
    up: float  # rise after the release (m)
    leave_speed: float

    @classmethod
    def draw(cls, rng: np.random.Generator, tempo: float) -> MugHangDraws:
        return cls(
            choice=float(rng.random()),
            standoff=float(rng.uniform(0.03, 0.05)),
            hover=float(rng.uniform(0.04, 0.07)),
            depth=float(rng.uniform(0.055, 0.075)),
            drop=float(rng.uniform(0.012, 0.016)),
            pick=PickDraws.draw(rng, PICK, tempo),
            carry_speed=speed(rng, tempo),
            align_speed=speed(rng, tempo, 0.05, 0.1),
            align_hold=int(rng.integers(1, 5)),
            insert_speed=speed(rng, tempo, 0.04, 0.07),
            seat_speed=speed(rng, tempo, 0.03, 0.05),
            release_hold=int(rng.integers(5, 10)),
            up=float(rng.uniform(0.08, 0.12)),
            leave_speed=speed(rng, tempo, 0.1, 0.2),
        )


class MugHangExpert(PickPlaceExpert):
    """MugHang (see the module docstring). :attr:`mug` holds the grasp."""

    version = "mug_hang-1"
    tasks = ("MugHang_D0", "MugHang_Moved")

    def task_plan(self, rng: np.random.Generator) -> list[Waypoint]:
        self.draws = d = MugHangDraws.draw(rng, self.tempo)
        self.mug, self.hanger_row = Grasp(self.entity_row("mug")), self.entity_row("hanger")
        #: Frozen at their first use: the EEF orientation of the hang, and the peg (root, axis).
        self.hang_rot: np.ndarray | None = None
        self.peg: tuple[np.ndarray, np.ndarray] | None = None
        at = partial(partial, self.opening_at)
        seat = -d.drop
        return [
            *self.pick(self.mug, PICK, d.pick),
            Waypoint("carry", at(s=PEG_LENGTH + d.standoff, dz=d.hover), 1.0, d.carry_speed, tol=0.015),
            Waypoint(
                "align",
                at(s=PEG_LENGTH + d.standoff),
                1.0,
                d.align_speed,
                tol=0.006,
                hold=d.align_hold,
                timeout=80,
                on_exit=self.regrasp,
            ),
            Waypoint("insert", at(s=d.depth), 1.0, d.insert_speed, tol=0.006, hold=2, timeout=100),
            Waypoint("seat", at(s=d.depth, dz=seat), 1.0, d.seat_speed, tol=0.006, timeout=40),
            Waypoint("release", at(s=d.depth, dz=seat), -1.0, 0.1, tol=1.0, hold=d.release_hold),
            Waypoint("leave", at(s=d.depth, dz=seat + d.up), -1.0, d.leave_speed, tol=0.02, timeout=60),
        ]

    def rot(self, obs: dict) -> np.ndarray:
        """EEF orientation that turns the mug's y axis along the peg's heading (order 2), frozen."""
        if self.hang_rot is None:
            u = token_pose(obs, self.hanger_row).r[:, 0]
            ref = math.atan2(u[1], u[0]) - math.pi / 2  # mug yaw whose y axis is along the peg
            self.hang_rot = aligned_eef_rotation(self.mug, self.home_heading(obs), ref, 2, self.draws.choice)
        return self.hang_rot

    def regrasp(self, obs: dict) -> None:
        """Measure ``G`` again before the slide: the mug may have turned in the fingers (about
        their closing axis) while it was carried; the slide then aims with where it really is."""
        self.mug.in_hand = token_pose(obs, 0).inverse() @ token_pose(obs, self.mug.row)

    def peg_axis(self, obs: dict) -> tuple[np.ndarray, np.ndarray]:
        """The peg's root and unit axis (world), read once."""
        if self.peg is None:
            hanger = token_pose(obs, self.hanger_row)
            self.peg = hanger.p.copy(), hanger.r[:, 0].copy()
        return self.peg

    def opening_at(self, obs: dict, s: float, dz: float = 0.0) -> Pose:
        """EEF pose that puts the opening's centre at ``a + s u``, ``dz`` higher."""
        root, u = self.peg_axis(obs)
        g = self.mug.in_hand
        r_mug = self.rot(obs) @ g.r
        q = root + s * u + np.array([0.0, 0.0, dz])
        return self.mug.eef_for(Pose(r_mug, q - r_mug @ OPENING))
