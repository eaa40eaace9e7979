"""Grasp-and-transport skills of the top-down experts: pick, place, align.

Grasps are top-down: EEF orientation ``top_down(psi)`` (:mod:`.frames`), with the heading
``psi`` drawn among the object's symmetric alternatives (``obj_yaw + 2 pi k / order``) that the
wrist can reach (:data:`.frames.TURN_RANGE`), so the same scene is solved with different grasps
(a multimodal action distribution).

A pick records the grasp ``G = T_eef^-1 T_obj`` (the object's pose in the EEF frame) when the
fingers have closed; a place then commands the EEF pose that puts the held object's origin at a
goal ``q`` with the EEF orientation ``r`` chosen for the place: ``p_eef = q - r G_p`` (from
``T_obj = T_eef G``), which corrects for where in the fingers the object actually ended up. What
a skill learns while it runs lives in a :class:`Grasp`, one per picked object
(:mod:`.relocate` builds on these skills).

Every skill draws its random choices in one place, in the order of its ``*Draws`` dataclass's
fields (:meth:`PickDraws.draw`, :meth:`PlaceDraws.draw`): the order is part of every
demonstration (see :mod:`.pick_place`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lerobot_actionflow import rotations
from lerobot_actionflow.experts import frames as fr
from lerobot_actionflow.experts.base import Waypoint
from lerobot_actionflow.experts.pose import Pose, token_pose

if TYPE_CHECKING:
    from lerobot_actionflow.experts.pick_place import PickPlaceExpert

#: Horizontal distances (m) from the robot base between which a leaning pick's lean grows from
#: 0 to full. Measured with robosuite 1.5.2's Panda (absolute OSC), the hand 3 cm over the
#: table: moved there on a slant from its home pose, top-down, it reaches 0.70 m with the elbow
#: (joint 4) at -1.4 rad, but 0.76 m straightens the elbow to its -0.07 rad limit with the
#: shoulder (joint 2) at its 1.76 rad limit, a pose the OSC cannot leave (commanded 0.2 m back,
#: the hand stays 11 cm off). With the wrist leaning towards the robot, 15 deg reaches 0.76 m and
#: 25 deg 0.80 m, the elbow at -1.2 / -1.1 rad.
LEAN_START, LEAN_FULL = 0.68, 0.78


def speed(rng: np.random.Generator, tempo: float, lo: float = 0.15, hi: float = 0.32) -> float:
    """One draw: a speed (m/s) uniform in ``[lo, hi)``, times the episode's ``tempo``."""
    return float(rng.uniform(lo, hi)) * tempo


@dataclass
class Grasp:
    """What the moves of one picked object learn as the episode runs (``None`` until then).

    Attributes:
        row: the object's row in ``obs["poses"]``.
        start_heading: heading ``psi`` of the measured EEF when the pick's approach began.
        eef: world EEF pose of the grasp, frozen when the descent begins.
        in_hand: ``G = T_eef^-1 T_obj``, the object's pose in the EEF frame, recorded when the
            fingers have closed.
        place: world EEF pose that puts the object's origin at the place goal (before the
            place's hover or release height is added), frozen when the carry begins.
    """

    row: int
    start_heading: float | None = None
    eef: Pose | None = None
    in_hand: Pose | None = None
    place: Pose | None = None

    def eef_for(self, obj: Pose) -> Pose:
        """EEF pose that puts the held object at the world pose ``obj``: ``T_obj G^-1``."""
        return obj @ self.in_hand.inverse()


# ------------------------------------------------------------------ pick
@dataclass(frozen=True)
class PickParams:
    """How to pick an object.

    Attributes:
        order: symmetry order about z: grasp headings ``obj_yaw + yaw_offset + 2 pi k / order``
            (0: continuous, any heading within 0.8 :data:`.frames.TURN_RANGE` of home).
        grasp_dz: grasp point height over the object's origin (m).
        xy_noise: half width (m) of the uniform xy noise added to the grasp point.
        grasp_offset: grasp point in the object frame, ``(x, y)`` (the height from the origin)
            or ``(x, y, z)`` (a point on a lying object: its height is taken from the point);
            ``None``: the origin. ``grasp_dz`` is added to the height either way.
        yaw_offset: heading of the grasp relative to the object's yaw (rad).
        approach_z: lowest world height (m) of the approach waypoint (to pass over a tower).
        descend_speed: range of the descent speed (m/s).
        avoid: ``obs -> world xy`` of an obstacle (a tower) that the hand, 0.2 m long along
            the finger axis (EEF x), must not sweep: when it stands within 0.2 m, the headings
            with the finger axis most nearly across the direction to it are kept.
        lean: lean the hand, wrist towards the robot, by ``lean_max`` (22-28 deg) times the ramp
            from :data:`LEAN_START` to :data:`LEAN_FULL` of the grasp point's distance from the
            robot base, keeping the headings whose EEF y axis is most nearly along that direction.
        lift_range: range of the lift height (m).
    """

    order: int
    grasp_dz: float
    xy_noise: float = 0.004
    grasp_offset: tuple[float, ...] | None = None
    yaw_offset: float = 0.0
    approach_z: float = 0.0
    descend_speed: tuple[float, float] = (0.06, 0.12)
    avoid: Callable[[dict], np.ndarray] | None = None
    lean: bool = False
    lift_range: tuple[float, float] = (0.10, 0.16)

    @property
    def offset(self) -> np.ndarray:
        """The grasp point in the object frame ``(3,)``."""
        if self.grasp_offset is None:
            return np.zeros(3)
        return np.array([*self.grasp_offset, 0.0][:3], dtype=np.float64)

    @property
    def height_from_point(self) -> bool:
        return self.grasp_offset is not None and len(self.grasp_offset) == 3


@dataclass(frozen=True)
class PickDraws:
    """The random choices of one pick, drawn in the order of the fields."""

    choice: float  # which of the admissible headings, in [0, 1)
    hover: float  # approach height over the grasp point (m)
    noise: np.ndarray  # (2,) xy offset of the grasp point (m)
    dz: float  # grasp height over the origin (or the point): grasp_dz +- 4 mm
    turn: float  # heading from home, for order 0
    lean_max: float  # full lean (rad); drawn only when params.lean, else 0
    lift: float  # lift height (m)
    approach_speed: float
    approach_hold: int
    descend_speed: float
    close_hold: int
    lift_speed: float

    @classmethod
    def draw(cls, rng: np.random.Generator, params: PickParams, tempo: float) -> PickDraws:
        return cls(
            choice=float(rng.random()),
            hover=float(rng.uniform(0.06, 0.12)),
            noise=rng.uniform(-params.xy_noise, params.xy_noise, 2),
            dz=params.grasp_dz + float(rng.uniform(-0.004, 0.004)),
            turn=float(rng.uniform(0.8 * fr.TURN_RANGE[0], 0.8 * fr.TURN_RANGE[1])),
            lean_max=math.radians(float(rng.uniform(22.0, 28.0))) if params.lean else 0.0,
            lift=float(rng.uniform(*params.lift_range)),
            approach_speed=speed(rng, tempo),
            approach_hold=int(rng.integers(0, 4)),
            descend_speed=speed(rng, tempo, *params.descend_speed),
            close_hold=int(rng.integers(8, 14)),
            lift_speed=speed(rng, tempo, 0.12, 0.25),
        )


class Pick:
    """Approach above the object (tracking it: objects may still settle after the reset),
    descend to the grasp pose (frozen as the descent begins), close, record ``G``, lift."""

    def __init__(self, expert: PickPlaceExpert, grasp: Grasp, params: PickParams, draws: PickDraws):
        self.expert, self.grasp, self.params, self.draws = expert, grasp, params, draws

    def waypoints(self, when: Callable[[dict], bool] | None = None) -> list[Waypoint]:
        d = self.draws
        return [
            Waypoint(
                "approach",
                self.above,
                -1.0,
                d.approach_speed,
                tol=0.015,
                hold=d.approach_hold,
                track=True,
                when=when,
            ),
            Waypoint("descend", self.grasp_pose, -1.0, d.descend_speed, tol=0.006, timeout=80, when=when),
            Waypoint(
                "close", self.grasp_pose, 1.0, 0.1, tol=1.0, hold=d.close_hold, on_exit=self.record, when=when
            ),
            Waypoint("lift", self.lift, 1.0, d.lift_speed, tol=0.02, timeout=80, when=when),
        ]

    def target(self, obs: dict) -> Pose:
        """The grasp pose for the object where it is now: over the grasp point (plus noise),
        ``top_down(psi, tilt)`` with the heading of :meth:`heading`."""
        prm, d, x = self.params, self.draws, self.expert
        obj = token_pose(obs, self.grasp.row)
        point = obj.apply(prm.offset)
        ramp = min(1.0, max(0.0, (x.reach(point) - LEAN_START) / (LEAN_FULL - LEAN_START)))
        tilt = d.lean_max * ramp
        to_robot = x.robot_base_xy() - point[:2]
        psi = self.heading(obs, obj, point, to_robot, tilt > 0.0)
        # The wrist moves by L sin(lean) along EEF y = (cos psi, sin psi): towards the robot.
        if math.cos(psi) * to_robot[0] + math.sin(psi) * to_robot[1] < 0.0:
            tilt = -tilt
        z = (point[2] if prm.height_from_point else obj.p[2]) + d.dz
        return Pose(fr.top_down(psi, tilt), np.array([point[0] + d.noise[0], point[1] + d.noise[1], z]))

    def heading(self, obs: dict, obj: Pose, point: np.ndarray, to_robot: np.ndarray, leaning: bool) -> float:
        """The grasp heading: for ``order`` 0, ``home + turn`` (or the current heading if that
        is 0.9 pi or more away); else one of :func:`.frames.symmetric_yaws`, narrowed by
        ``avoid`` and ``lean`` (:class:`PickParams`), chosen by ``choice``."""
        prm = self.params
        home = self.expert.home_heading(obs)
        if self.grasp.start_heading is None:
            self.grasp.start_heading = self.expert.eef_heading(obs)
        current = home + fr.wrap(self.grasp.start_heading - home)
        if prm.order == 0:
            psi = home + self.draws.turn
            return current if abs(psi - current) > 0.9 * math.pi else psi
        yaws = fr.symmetric_yaws(fr.yaw_of(obj.r) + prm.yaw_offset, prm.order, home, current)
        if prm.avoid is not None:
            tower = np.asarray(prm.avoid(obs), dtype=np.float64)[:2] - obj.p[:2]
            if float(np.linalg.norm(tower)) <= 0.2:
                yaws = fr.across(yaws, tower)
        if leaning:
            yaws = fr.across(yaws, to_robot)
        return fr.pick_one(yaws, self.draws.choice)

    def above(self, obs: dict) -> Pose:
        g = self.target(obs)
        return Pose(g.r, np.array([g.p[0], g.p[1], max(g.p[2] + self.draws.hover, self.params.approach_z)]))

    def grasp_pose(self, obs: dict) -> Pose:
        if self.grasp.eef is None:
            self.grasp.eef = self.target(obs)
        return self.grasp.eef

    def record(self, obs: dict) -> None:
        self.grasp.in_hand = token_pose(obs, 0).inverse() @ token_pose(obs, self.grasp.row)

    def lift(self, obs: dict) -> Pose:
        return self.grasp_pose(obs).raised(self.draws.lift)


# ------------------------------------------------------------------ place
@dataclass(frozen=True)
class PlaceParams:
    """How to place a held object.

    Attributes:
        hover: range of the carry height over the place pose (m).
        release_dz: range of the release height over the place pose (m).
        carry_z: lowest world height (m) of the carry waypoint, if any.
        lower_speed: range of the speed (m/s) of the final descent.
        up: range of the retreat height (m).
        lower_timeout: steps after which the descent ends anyway (a jammed piece is released).
    """

    hover: tuple[float, float] = (0.05, 0.09)
    release_dz: tuple[float, float] = (0.0, 0.006)
    carry_z: float | None = None
    lower_speed: tuple[float, float] = (0.05, 0.1)
    up: tuple[float, float] = (0.06, 0.12)
    lower_timeout: int = 80


@dataclass(frozen=True)
class PlaceDraws:
    """The random choices of one place, drawn in the order of the fields."""

    hover: float
    release_dz: float
    up: float
    carry_speed: float
    carry_hold: int
    lower_speed: float
    release_hold: int
    retreat_speed: float

    @classmethod
    def draw(cls, rng: np.random.Generator, params: PlaceParams, tempo: float) -> PlaceDraws:
        return cls(
            hover=float(rng.uniform(*params.hover)),
            release_dz=float(rng.uniform(*params.release_dz)),
            up=float(rng.uniform(*params.up)),
            carry_speed=speed(rng, tempo),
            carry_hold=int(rng.integers(0, 4)),
            lower_speed=speed(rng, tempo, *params.lower_speed),
            release_hold=int(rng.integers(5, 10)),
            retreat_speed=speed(rng, tempo, 0.1, 0.2),
        )


class Place:
    """Carry the object held per ``grasp`` so that its origin reaches ``goal(obs)`` (a world
    position, read once, when the carry begins), lower it, release it, retreat upwards.

    ``rot(obs)`` gives the EEF orientation of the place (default: the grasp's)."""

    def __init__(
        self,
        grasp: Grasp,
        goal: Callable[[dict], np.ndarray],
        params: PlaceParams,
        draws: PlaceDraws,
        rot: Callable[[dict], np.ndarray] | None = None,
    ):
        self.grasp, self.goal, self.params, self.draws, self.rot = grasp, goal, params, draws, rot

    def waypoints(self, when: Callable[[dict], bool] | None = None) -> list[Waypoint]:
        d, prm = self.draws, self.params
        return [
            Waypoint(
                "carry", self.carry, 1.0, d.carry_speed, tol=0.015, hold=d.carry_hold, timeout=120, when=when
            ),
            Waypoint(
                "lower",
                self.release_pose,
                1.0,
                d.lower_speed,
                tol=0.006,
                timeout=prm.lower_timeout,
                when=when,
            ),
            Waypoint("release", self.release_pose, -1.0, 0.1, tol=1.0, hold=d.release_hold, when=when),
            Waypoint("retreat", self.retreat, -1.0, d.retreat_speed, tol=0.02, timeout=60, when=when),
        ]

    def eef_at(self, obs: dict, dz: float) -> Pose:
        """The place pose ``(r, q - r G_p)`` (frozen at the first call), ``dz`` higher."""
        g = self.grasp
        if g.place is None:
            r = g.eef.r if self.rot is None else self.rot(obs)
            q = np.asarray(self.goal(obs), dtype=np.float64)
            g.place = Pose(r, q - r @ g.in_hand.p)
        return g.place.raised(dz)

    def carry(self, obs: dict) -> Pose:
        t = self.eef_at(obs, self.draws.hover)
        if self.params.carry_z is None:
            return t
        return Pose(t.r, np.array([t.p[0], t.p[1], max(t.p[2], self.params.carry_z)]))

    def release_pose(self, obs: dict) -> Pose:
        return self.eef_at(obs, self.draws.release_dz)

    def retreat(self, obs: dict) -> Pose:
        return self.eef_at(obs, self.draws.release_dz).raised(self.draws.up)


def aligned_eef_rotation(
    grasp: Grasp,
    home: float,
    ref_yaw: float,
    order: int,
    choice: float,
    prefer: Callable[[float], bool] | None = None,
) -> np.ndarray:
    """EEF orientation that turns the object held per ``grasp`` about world z by ``d`` so that
    its yaw equals ``ref_yaw`` modulo ``2 pi / order`` (a square peg or socket: order 4):
    ``Rz(d) r_grasp``.

    Among ``d = d0 + 2 pi k / order`` (``k = -order..order``, ``d0 = wrap(ref_yaw - obj_yaw)``)
    those keep the wrist's turn from home within :data:`.frames.TURN_RANGE` and ``|d| < 0.9 pi``;
    of those, the ones whose resulting object yaw satisfies ``prefer`` if any do; if none is
    left, the smallest ``|d|``. ``choice`` in ``[0, 1)`` picks one."""
    r_eef = grasp.eef.r
    turn = fr.wrap(fr.heading(r_eef) - home)
    obj_yaw = fr.yaw_of(r_eef @ grasp.in_hand.r)
    d0 = fr.wrap(ref_yaw - obj_yaw)
    step = 2 * math.pi / order
    cands = [d0 + k * step for k in range(-order, order + 1)]
    lo, hi = fr.TURN_RANGE
    ds = [d for d in cands if lo <= turn + d <= hi and abs(d) < 0.9 * math.pi]
    if prefer is not None:
        ds = [d for d in ds if prefer(obj_yaw + d)] or ds
    ds = ds or [min(cands, key=abs)]
    return rotations.yaw_matrix(fr.pick_one(ds, choice)) @ r_eef
