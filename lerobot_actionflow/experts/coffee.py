"""Coffee expert: drop the pod into the holder, then close the lid by pushing it along its arc.

Lid geometry in the holder frame ``H`` (the site at the holder floor's centre, x towards the
machine's front; :mod:`lerobot_actionflow.envs.coffee`): the hinge is at
``h = (-HOLDER_OUTER_RADIUS, 0, HOLDER_DEPTH)``; a lid opened by ``a`` points along
``d(a) = (cos a, 0, sin a)`` from it, and its back face's normal is ``n(a) = (-sin a, 0, cos a)``.
The push waypoints are ``h + radius d(a) + delta n(a)`` for the decreasing angles
:data:`PUSH_ANGLES`, with the closed fingers.

The open lid stands (leaning 10 deg back) just behind the holder's back rim, at ``x_H =
-0.032``. The Panda hand is 0.20 m long along the finger axis (EEF x) and 0.064 m deep across
it, so the pod is lowered with the finger axis along the holder's y axis (EEF heading
``psi = yaw_H`` or ``yaw_H + pi``, whichever the wrist reaches, at random): the hand then clears
the lid by a few mm, while any other heading strikes it, tilts the pod in the cup and leaves
the lid resting on the tilted pod. The pod is aimed a little forward of the holder axis
(``+x_H``) for the same clearance, and carried there above the lid's top.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from lerobot_actionflow.envs.coffee import HOLDER_DEPTH, HOLDER_OUTER_RADIUS, POD_HALF_HEIGHT
from lerobot_actionflow.experts import frames as fr
from lerobot_actionflow.experts.base import Waypoint
from lerobot_actionflow.experts.pick_place import PickPlaceExpert
from lerobot_actionflow.experts.pose import Pose, token_pose
from lerobot_actionflow.experts.skills import (
    Grasp,
    PickDraws,
    PickParams,
    PlaceDraws,
    PlaceParams,
    speed,
)

#: Lid angles (rad) of the push: from behind the open lid (105 deg) to past shut (-5 deg).
PUSH_ANGLES = np.radians([105.0, 90.0, 70.0, 50.0, 30.0, 10.0, -5.0])
#: The pod, at any heading.
PICK = PickParams(order=0, grasp_dz=0.0, xy_noise=0.002)
#: ``carry_z`` is drawn per episode (``safe_z``).
PLACE = PlaceParams(hover=(0.04, 0.07), release_dz=(0.0, 0.005))


@dataclass(frozen=True)
class CoffeeDraws:
    """The random choices of a Coffee episode (after the tempo), in the order of the fields."""

    drop: float  # release height of the pod's bottom over the holder floor (m)
    forward: float  # aim point forward of the holder axis, along x_H (m)
    radius: float  # push point's distance from the hinge along the lid (m)
    delta: float  # push point's distance behind the lid's back face (m)
    choice: float  # which of the two headings over the holder, in [0, 1)
    push_speeds: tuple[float, ...]  # one per angle after the first
    # Height (m) of the hand with the pod over the open lid's top (1.02 m) before it moves
    # sideways: a diagonal climb from the pod to the holder hits the lid.
    safe_z: float
    place: PlaceDraws
    pick: PickDraws
    rise_speed: float
    close_speed: float
    behind_speed: float
    leave_speed: float

    @classmethod
    def draw(cls, rng: np.random.Generator, tempo: float) -> CoffeeDraws:
        return cls(
            drop=float(rng.uniform(0.01, 0.02)),
            forward=float(rng.uniform(0.002, 0.005)),
            radius=float(rng.uniform(0.04, 0.05)),
            delta=float(rng.uniform(0.025, 0.035)),
            choice=float(rng.random()),
            push_speeds=tuple(speed(rng, tempo, 0.05, 0.1) for _ in PUSH_ANGLES[1:]),
            safe_z=float(rng.uniform(1.07, 1.10)),
            place=PlaceDraws.draw(rng, PLACE, tempo),
            pick=PickDraws.draw(rng, PICK, tempo),
            rise_speed=speed(rng, tempo),
            close_speed=speed(rng, tempo),
            behind_speed=speed(rng, tempo, 0.05, 0.1),
            leave_speed=speed(rng, tempo, 0.1, 0.2),
        )


class CoffeeExpert(PickPlaceExpert):
    """Coffee: pick the pod, rise over the lid, drop the pod into the holder, push the lid shut.
    :attr:`pod` holds the grasp; its ``place`` orientation is kept for the push."""

    version = "coffee-2"
    tasks = ("Coffee_D0", "Coffee_D1", "Coffee_D2")

    def task_plan(self, rng: np.random.Generator) -> list[Waypoint]:
        self.draws = d = CoffeeDraws.draw(rng, self.tempo)
        self.pod, self.holder_row = Grasp(self.entity_row("pod")), self.entity_row("holder")
        place = replace(PLACE, carry_z=d.safe_z)
        first, last = PUSH_ANGLES[0], PUSH_ANGLES[-1]
        pushes = [
            Waypoint(f"push{i}", partial(self.push_point, a=a), 1.0, v, tol=0.01, timeout=40)
            for i, (a, v) in enumerate(zip(PUSH_ANGLES[1:], d.push_speeds, strict=True))
        ]
        return [
            *self.pick(self.pod, PICK, d.pick),
            Waypoint("rise", self.rise, 1.0, d.rise_speed, tol=0.02, timeout=60),
            *self.place(self.pod, self.in_holder, place, d.place, rot=self.clear_of_lid),
            Waypoint(
                "close_fingers", partial(self.push_point, a=first, lift=0.08), 1.0, d.close_speed, tol=0.015
            ),
            Waypoint("behind_lid", partial(self.push_point, a=first), 1.0, d.behind_speed, tol=0.01),
            *pushes,
            Waypoint("leave", partial(self.push_point, a=last, lift=0.08), 1.0, d.leave_speed, tol=0.02),
        ]

    def rise(self, obs: dict) -> Pose:
        """Straight up from the grasp to ``safe_z``."""
        g = self.pod.eef
        return Pose(g.r, np.array([g.p[0], g.p[1], self.draws.safe_z]))

    def in_holder(self, obs: dict) -> np.ndarray:
        d = self.draws
        return token_pose(obs, self.holder_row).apply(np.array([d.forward, 0.0, POD_HALF_HEIGHT + d.drop]))

    def clear_of_lid(self, obs: dict) -> np.ndarray:
        """Top-down with the finger axis along holder y: ``psi`` in ``{yaw_H, yaw_H + pi}``."""
        yaw_h = fr.yaw_of(token_pose(obs, self.holder_row).r)
        current = fr.heading(self.pod.eef.r)
        home = self.home_heading(obs)
        yaws = fr.symmetric_yaws(yaw_h, 2, home, home + fr.wrap(current - home))
        return fr.top_down(fr.pick_one(yaws, self.draws.choice))

    def push_point(self, obs: dict, a: float, lift: float = 0.0) -> Pose:
        """``h + radius d(a) + delta n(a)`` in the holder frame, ``lift`` higher, with the
        place's EEF orientation."""
        d = self.draws
        hinge = np.array([-HOLDER_OUTER_RADIUS, 0.0, HOLDER_DEPTH])
        local = hinge + d.radius * np.array([math.cos(a), 0.0, math.sin(a)])
        local = local + d.delta * np.array([-math.sin(a), 0.0, math.cos(a)])
        return Pose(self.pod.place.r, token_pose(obs, self.holder_row).apply(local)).raised(lift)
