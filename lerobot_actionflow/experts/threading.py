"""Threading expert: grasp the needle's handle, turn the needle along the ring's axis, push
its tip through the ring.

With the needle held (grasp ``G``, :class:`~lerobot_actionflow.experts.skills.Grasp`), its tip is
at ``T_eef G t`` (``t = (NEEDLE_TIP_X, 0, 0)`` in the needle frame). The EEF target that puts the
tip at ``c - s u`` (``c`` the ring centre, ``u`` the tip direction made horizontal, ``s`` the
stand-off along it) keeps the EEF orientation ``r`` and sets ``p_eef = c - s u - r (G_r t + G_p)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from lerobot_actionflow.envs.threading_task import NEEDLE_TIP_X
from lerobot_actionflow.experts import frames as fr
from lerobot_actionflow.experts.base import Waypoint
from lerobot_actionflow.experts.pick_place import PickPlaceExpert
from lerobot_actionflow.experts.pose import Pose, token_pose
from lerobot_actionflow.experts.skills import (
    Grasp,
    PickDraws,
    PickParams,
    aligned_eef_rotation,
    speed,
)

#: Centre of the needle's handle on its x axis (m). Mirrors the handle geom's location in
#: ``envs.threading_task.make_needle``, which that module does not name.
HANDLE_X = -0.045
#: The handle, across its width (two headings); ``grasp_offset`` is drawn per episode.
PICK = PickParams(order=2, grasp_dz=0.0, xy_noise=0.002, yaw_offset=-math.pi / 2)


@dataclass(frozen=True)
class ThreadingDraws:
    """The random choices of a Threading episode (after the tempo), in the order of the fields."""

    choice: float  # which of the two needle directions along the ring's axis, in [0, 1)
    standoff: float  # tip distance in front of the ring's centre before the push (m)
    hover: float  # carry height over the aligned pose (m)
    through: float  # final tip position along the axis from the ring's centre (m; < 0: short of it)
    handle_x: float  # grasp point on the needle's x axis: HANDLE_X +- 8 mm
    pick: PickDraws
    carry_speed: float
    align_speed: float
    align_hold: int
    insert_speed: float

    @classmethod
    def draw(cls, rng: np.random.Generator, tempo: float) -> ThreadingDraws:
        return cls(
            choice=float(rng.random()),
            standoff=float(rng.uniform(0.03, 0.05)),
            hover=float(rng.uniform(0.03, 0.06)),
            through=float(rng.uniform(-0.004, 0.002)),
            handle_x=HANDLE_X + float(rng.uniform(-0.008, 0.008)),
            pick=PickDraws.draw(rng, PICK, tempo),
            carry_speed=speed(rng, tempo),
            align_speed=speed(rng, tempo, 0.05, 0.1),
            align_hold=int(rng.integers(1, 5)),
            insert_speed=speed(rng, tempo, 0.03, 0.06),
        )


class ThreadingExpert(PickPlaceExpert):
    """Threading: pick the needle by its handle (two headings), turn it parallel to the ring's
    axis (the direction of the two that the wrist reaches, at random), bring the tip in front of
    the ring, then push it along the axis into the ring's centre. :attr:`needle` holds the grasp."""

    version = "threading-1"
    tasks = ("Threading_D0", "Threading_D1", "Threading_D2")

    def task_plan(self, rng: np.random.Generator) -> list[Waypoint]:
        self.draws = d = ThreadingDraws.draw(rng, self.tempo)
        self.needle, self.ring_row = Grasp(self.entity_row("needle")), self.entity_row("ring")
        #: Frozen at their first use: the EEF orientation of the push, and the ring's centre.
        self.push_rot: np.ndarray | None = None
        self.ring_centre: np.ndarray | None = None
        return [
            *self.pick(self.needle, replace(PICK, grasp_offset=(d.handle_x, 0.0)), d.pick),
            Waypoint("carry", self.over_standoff, 1.0, d.carry_speed, tol=0.01, timeout=120),
            Waypoint("align", self.at_standoff, 1.0, d.align_speed, tol=0.004, hold=d.align_hold, timeout=80),
            Waypoint("insert", self.through_ring, 1.0, d.insert_speed, tol=0.003, hold=10, timeout=100),
        ]

    def rot(self, obs: dict) -> np.ndarray:
        """EEF orientation that turns the needle along the ring's axis (order 2), frozen."""
        if self.push_rot is None:
            ring_yaw = fr.yaw_of(token_pose(obs, self.ring_row).r)
            home = self.home_heading(obs)
            self.push_rot = aligned_eef_rotation(self.needle, home, ring_yaw, 2, self.draws.choice)
        return self.push_rot

    def eef_for_tip(self, obs: dict, s: float, dz: float = 0.0) -> Pose:
        """EEF pose with the tip at ``c - s u``, ``dz`` higher (module docstring)."""
        r = self.rot(obs)
        g = self.needle.in_hand
        u = (r @ g.r)[:, 0]
        u = u - u[2] * np.array([0.0, 0.0, 1.0])
        u /= np.linalg.norm(u)
        if self.ring_centre is None:
            self.ring_centre = self.object_xyz(obs, self.ring_row)
        p = self.ring_centre - s * u - r @ g.apply(np.array([NEEDLE_TIP_X, 0.0, 0.0]))
        return Pose(r, p).raised(dz)

    def over_standoff(self, obs: dict) -> Pose:
        return self.eef_for_tip(obs, self.draws.standoff, self.draws.hover)

    def at_standoff(self, obs: dict) -> Pose:
        return self.eef_for_tip(obs, self.draws.standoff)

    def through_ring(self, obs: dict) -> Pose:
        return self.eef_for_tip(obs, self.draws.through)
