"""Pick-and-place building blocks and the cube experts (Lift, StackThree).

Grasps are top-down: EEF orientation ``Rz(psi) R_DOWN`` (:func:`frames.top_down`), with the
heading ``psi`` drawn among the object's symmetric alternatives (``obj_yaw + 2 pi k / order``)
that the wrist can reach (:data:`frames.TURN_RANGE`), so the same scene is solved
with different grasps (a multimodal action distribution).

A pick records the grasp transform ``G = T_eef^-1 T_obj`` when the gripper has closed; a place
then commands the EEF pose that puts the held object at a goal position ``q`` with the EEF
orientation ``R`` kept: ``p_eef = q - R G_p`` (from ``T_obj = T_eef G``). Placing therefore
corrects for where in the fingers the object actually ended up.

Far from the robot a top-down hand straightens the Panda's arm into a pose it cannot leave.
:meth:`PickPlaceExpert.relocate` picks such an object with the hand leaning towards the robot
(:func:`frames.top_down` ``lean``, about the fingers' closing axis) and sets it down nearer,
where the ordinary top-down pick takes it: a leaning pinch does not hold a piece level well
enough for an insertion, but setting it down on the table needs no precision.
"""

from __future__ import annotations

import math

import numpy as np

from lerobot_actionflow.experts import frames as fr
from lerobot_actionflow.experts.base import Pose, Waypoint, WaypointExpert

TABLE_Z = 0.8
#: Horizontal distances (m) from the robot base between which a leaning pick's lean grows from
#: 0 to full. Measured with robosuite 1.5.2's Panda (absolute OSC), the hand 3 cm over the
#: table: moved there on a slant from its home pose, top-down, it reaches 0.70 m with the elbow
#: (joint 4) at -1.4 rad, but 0.76 m straightens the elbow to its -0.07 rad limit with the
#: shoulder (joint 2) at its 1.76 rad limit, a pose the OSC cannot leave (commanded 0.2 m back,
#: the hand stays 11 cm off). With the wrist leaning towards the robot, 15 deg reaches 0.76 m and
#: 25 deg 0.80 m, the elbow at -1.2 / -1.1 rad.
LEAN_START, LEAN_FULL = 0.68, 0.78
#: An object at least this far (m, horizontally) from the robot base is relocated before its
#: pick. Lowered from 0.95 m straight down, as a pick does, the top-down hand reaches 0.77 m
#: (elbow -0.75 rad) but stops 2 cm short of 0.80 m and is caught as above.
RELOCATE_FROM = 0.74


def entity_row(env, name: str) -> int:
    """Row of entity ``name`` in ``obs["poses"]`` (row 0 is the EEF)."""
    return 1 + [e.name for e in env.spec_task.entities].index(name)


def obj_pose(obs: dict, row: int) -> Pose:
    return fr.pose_from_row(obs["poses"][row])


def eef_heading(obs: dict) -> float:
    """``psi`` of the current EEF orientation, as in ``top_down(psi)``."""
    return fr.yaw_of(fr.pose_from_row(obs["poses"][0])[1]) - math.pi / 2


class PickPlaceExpert(WaypointExpert):
    """Helpers that build pick / place / retreat waypoint sequences with random parameters."""

    def _speed(self, rng, lo=0.15, hi=0.32) -> float:
        return float(rng.uniform(lo, hi)) * self.tempo

    def robot_base_xy(self) -> np.ndarray:
        return np.asarray(self.env.robosuite_env.robots[0].base_pos[:2], dtype=np.float64)

    def reach(self, p) -> float:
        """Horizontal distance (m) of world point ``p`` from the robot base."""
        return float(np.linalg.norm(np.asarray(p, dtype=np.float64)[:2] - self.robot_base_xy()))

    def plan(self, rng: np.random.Generator) -> list[Waypoint]:
        self.tempo = float(rng.uniform(0.8, 1.2))
        return self.task_plan(rng)

    def task_plan(self, rng: np.random.Generator) -> list[Waypoint]:
        raise NotImplementedError

    # -------------------------------------------------------------- pick
    def pick(
        self,
        rng: np.random.Generator,
        row: int,
        key: str,
        order: int,
        grasp_dz: float,
        xy_noise: float = 0.004,
        grasp_offset: tuple[float, ...] | None = None,
        yaw_offset: float = 0.0,
        approach_z: float = 0.0,
        descend_speed: tuple[float, float] = (0.06, 0.12),
        avoid=None,
        lean: bool = False,
        lift_range: tuple[float, float] = (0.10, 0.16),
        when=None,
    ) -> list[Waypoint]:
        """Approach above entity ``row``, descend, close, lift.

        ``order``: symmetry order about z (0: continuous, any heading); ``grasp_dz``: grasp point
        height over the entity origin; ``grasp_offset``: grasp point (x, y) in the entity frame
        (default its origin), or (x, y, z), then also giving the grasp height (``grasp_dz`` is
        added to it); ``yaw_offset``: heading of the grasp relative to the entity's yaw;
        ``approach_z``: lowest world height of the approach waypoint (to pass over a tower built
        before); ``descend_speed``: range of the descent speed (m/s); ``avoid(obs)``: optional
        world xy of an obstacle (a tower) that the hand, 0.2 m long along the finger axis (EEF
        x), must not sweep: among the symmetric headings those with the finger axis most nearly
        across the direction to it are kept; ``lean``: lean the hand with the wrist towards the
        robot, by ``lean_max`` (22-28 deg) times the ramp from :data:`LEAN_START` to
        :data:`LEAN_FULL` of the grasp point's distance from the robot base, keeping the
        headings whose EEF y axis lies most nearly along that direction; ``lift_range``: range of
        the lift height (m); ``when``: the waypoints' condition (:class:`Waypoint`).

        Stores the grasp transform in ``mem[key]``."""
        choice = float(rng.random())
        hover = float(rng.uniform(0.06, 0.12))
        noise = rng.uniform(-xy_noise, xy_noise, 2)
        dz = grasp_dz + float(rng.uniform(-0.004, 0.004))
        off = np.zeros(3) if grasp_offset is None else np.array([*grasp_offset, 0.0][:3], dtype=np.float64)
        # A 3-D offset (x, y, z) is a grasp point on a lying object: its height comes from it too.
        grasp_z_from_point = grasp_offset is not None and len(grasp_offset) == 3
        cont_turn = float(rng.uniform(0.8 * fr.TURN_RANGE[0], 0.8 * fr.TURN_RANGE[1]))
        lean_max = math.radians(float(rng.uniform(22.0, 28.0))) if lean else 0.0

        def live_grasp(obs) -> Pose:
            p_o, r_o = obj_pose(obs, row)
            p = p_o + r_o @ off
            ramp = min(1.0, max(0.0, (self.reach(p) - LEAN_START) / (LEAN_FULL - LEAN_START)))
            tilt = lean_max * ramp
            to_robot = self.robot_base_xy() - p[:2]
            mem = self.state.mem
            home = mem.setdefault("psi_home", eef_heading(obs))
            cur = home + fr.wrap(mem.setdefault(key + "_psi0", eef_heading(obs)) - home)
            if order == 0:
                psi = home + cont_turn
                if abs(psi - cur) > 0.9 * math.pi:
                    psi = cur
            else:
                yaws = fr.symmetric_yaws(fr.yaw_of(r_o) + yaw_offset, order, home, cur)
                tower = None if avoid is None else np.asarray(avoid(obs), dtype=np.float64)[:2] - p_o[:2]
                if tower is not None and float(np.linalg.norm(tower)) <= 0.2:
                    yaws = across(yaws, tower)
                if tilt > 0.0:
                    yaws = across(yaws, to_robot)
                psi = yaws[min(int(choice * len(yaws)), len(yaws) - 1)]
            # The wrist moves by L sin(lean) along EEF y = (cos psi, sin psi): towards the robot.
            if math.cos(psi) * to_robot[0] + math.sin(psi) * to_robot[1] < 0.0:
                tilt = -tilt
            z = (p[2] if grasp_z_from_point else p_o[2]) + dz
            return np.array([p[0] + noise[0], p[1] + noise[1], z]), fr.top_down(psi, tilt)

        def across(yaws: list[float], d: np.ndarray) -> list[float]:
            # |cos| of the angle between the finger axis (heading psi + pi/2) and d: keep the
            # headings within 0.1 of the best one.
            h = math.atan2(d[1], d[0])
            score = [abs(math.cos(y + math.pi / 2 - h)) for y in yaws]
            return [y for y, c in zip(yaws, score, strict=True) if c <= min(score) + 0.1]

        def grasp_pose(obs, mem) -> Pose:
            # Frozen at the start of the descent; the approach tracks the object live (objects
            # may still be settling after the reset).
            if key + "_pose" not in mem:
                mem[key + "_pose"] = live_grasp(obs)
            return mem[key + "_pose"]

        def above(obs, mem) -> Pose:
            p, r = live_grasp(obs)
            return np.array([p[0], p[1], max(p[2] + hover, approach_z)]), r

        def record(obs, mem) -> None:
            eef = fr.pose_from_row(obs["poses"][0])
            mem[key] = fr.compose(fr.inverse(eef), obj_pose(obs, row))

        def lift(obs, mem) -> Pose:
            p, r = grasp_pose(obs, mem)
            return p + np.array([0.0, 0.0, lift_h]), r

        lift_h = float(rng.uniform(*lift_range))
        # Draw the speed before the pause, as before: the other experts keep their demonstrations.
        return [
            Waypoint(
                "approach",
                above,
                -1.0,
                self._speed(rng),
                tol=0.015,
                hold=int(rng.integers(0, 4)),
                track=True,
                when=when,
            ),
            Waypoint(
                "descend",
                grasp_pose,
                -1.0,
                self._speed(rng, *descend_speed),
                tol=0.006,
                timeout=80,
                when=when,
            ),
            Waypoint(
                "close",
                grasp_pose,
                1.0,
                0.1,
                tol=1.0,
                hold=int(rng.integers(8, 14)),
                on_exit=record,
                when=when,
            ),
            Waypoint("lift", lift, 1.0, self._speed(rng, 0.12, 0.25), tol=0.02, timeout=80, when=when),
        ]

    # -------------------------------------------------------------- place
    def place(
        self,
        rng: np.random.Generator,
        key: str,
        goal,
        hover: tuple[float, float] = (0.05, 0.09),
        release_dz: tuple[float, float] = (0.0, 0.006),
        carry_z: float | None = None,
        rot=None,
        lower_speed: tuple[float, float] = (0.05, 0.1),
        up: tuple[float, float] = (0.06, 0.12),
        lower_timeout: int = 80,
        when=None,
    ) -> list[Waypoint]:
        """Carry the object held per ``mem[key]`` so that its origin reaches ``goal(obs, mem)``
        (a world position), release it, and retreat upwards. ``rot(obs, mem)`` optionally gives
        the EEF orientation for the place (default: the one held during the pick);
        ``lower_speed``: range of the speed (m/s) of the final descent; ``up``: range of the
        retreat height (m); ``lower_timeout``: steps after which the descent ends anyway (a
        jammed piece is released there); ``when``: the waypoints' condition (:class:`Waypoint`)."""
        h = float(rng.uniform(*hover))
        rdz = float(rng.uniform(*release_dz))
        up = float(rng.uniform(*up))

        def eef_for(obs, mem, dz: float) -> Pose:
            if key + "_goal" not in mem:
                r = mem[key + "_pose"][1] if rot is None else rot(obs, mem)
                q = np.asarray(goal(obs, mem), dtype=np.float64)
                g_p = mem[key][0]
                mem[key + "_goal"] = (q - r @ g_p, r)
            p, r = mem[key + "_goal"]
            return p + np.array([0.0, 0.0, dz]), r

        def carry(obs, mem) -> Pose:
            p, r = eef_for(obs, mem, h)
            if carry_z is not None:
                p[2] = max(p[2], carry_z)
            return p, r

        def release_pose(obs, mem) -> Pose:
            return eef_for(obs, mem, rdz)

        def retreat(obs, mem) -> Pose:
            p, r = eef_for(obs, mem, rdz)
            return p + np.array([0.0, 0.0, up]), r

        return [
            Waypoint(
                "carry",
                carry,
                1.0,
                self._speed(rng),
                tol=0.015,
                hold=int(rng.integers(0, 4)),
                timeout=120,
                when=when,
            ),
            Waypoint(
                "lower",
                release_pose,
                1.0,
                self._speed(rng, *lower_speed),
                tol=0.006,
                timeout=lower_timeout,
                when=when,
            ),
            Waypoint("release", release_pose, -1.0, 0.1, tol=1.0, hold=int(rng.integers(5, 10)), when=when),
            Waypoint("retreat", retreat, -1.0, self._speed(rng, 0.1, 0.2), tol=0.02, timeout=60, when=when),
        ]

    # -------------------------------------------------------------- relocate
    def relocate(
        self,
        rng: np.random.Generator,
        row: int,
        key: str,
        order: int,
        grasp_dz: float,
        others: tuple[int, ...],
    ) -> list[Waypoint]:
        """If entity ``row`` lies :data:`RELOCATE_FROM` or further from the robot base when these
        waypoints are reached (``mem[key + "_relocated"]``), pick it with a leaning hand
        (:meth:`pick` ``lean``), carry it low (5-7 cm up) and set it down on the table 0.62-0.66 m
        from the base, on the line from the base through it, turned about the base (steps of
        0.12 rad) until it is 0.13 m or more from the entities ``others``; otherwise the
        waypoints are skipped. The object keeps its yaw. These moves run 1.3 times the episode's
        tempo (they need no precision, and the episode's time limit is shared with the task)."""
        r_spot = float(rng.uniform(0.62, 0.66))
        drop = float(rng.uniform(0.002, 0.006))
        tempo, self.tempo = self.tempo, 1.3 * self.tempo

        def far(obs, mem) -> bool:
            if key + "_relocated" not in mem:
                p = obs["poses"][row, :3].astype(np.float64)
                mem[key + "_relocated"] = self.reach(p) >= RELOCATE_FROM
                if mem[key + "_relocated"]:
                    mem[key + "_spot"] = np.array([*self._clear_spot(obs, p, r_spot, others), p[2] + drop])
            return mem[key + "_relocated"]

        held = key + "_lean"
        waypoints = [
            *self.pick(
                rng,
                row,
                held,
                order=order,
                grasp_dz=grasp_dz,
                xy_noise=0.002,
                lean=True,
                lift_range=(0.05, 0.07),
                when=far,
            ),
            *self.place(
                rng,
                held,
                lambda obs, mem: mem[key + "_spot"],
                hover=(0.02, 0.04),
                release_dz=(0.0, 0.002),
                carry_z=TABLE_Z + 0.07,
                lower_speed=(0.1, 0.16),
                up=(0.04, 0.06),
                when=far,
            ),
        ]
        self.tempo = tempo
        return waypoints

    def _clear_spot(self, obs: dict, p: np.ndarray, r: float, others: tuple[int, ...]) -> np.ndarray:
        base = self.robot_base_xy()
        a0 = math.atan2(p[1] - base[1], p[0] - base[0])
        spots = [
            base + r * np.array([math.cos(a0 + 0.12 * k), math.sin(a0 + 0.12 * k)]) for k in range(-4, 5)
        ]
        spots.sort(key=lambda q: float(np.linalg.norm(q - p[:2])))
        for q in spots:
            if all(float(np.linalg.norm(q - obs["poses"][o, :2])) >= 0.13 for o in others):
                return q
        return spots[0]


class LiftExpert(PickPlaceExpert):
    """Lift: top-down grasp of the cube at one of its four headings, then lift 0.10-0.16 m."""

    version = "lift-1"
    tasks = ("Lift",)

    def task_plan(self, rng):
        return self.pick(rng, entity_row(self.env, "cube"), "cube", order=4, grasp_dz=0.0)


class StackThreeExpert(PickPlaceExpert):
    """StackThree: pick A (4 headings), place it on B, pick C, place it on A.

    Version 3 descends and lowers faster (version 2 ran out of the 400 steps while lowering C in
    3 of 4 failed D2 episodes) and grasps C with the hand across the direction to the tower when
    C lies within 0.2 m of it (the 0.2 m long hand swept A off B)."""

    version = "stack_three-3"
    tasks = ("StackThree_D0", "StackThree_D1", "StackThree_D2")

    def task_plan(self, rng):
        a, b, c = (entity_row(self.env, n) for n in ("cubeA", "cubeB", "cubeC"))

        def on_b(obs, mem):
            return obs["poses"][b, :3] + np.array([0.0, 0.0, 0.025 + 0.02])

        def on_a(obs, mem):
            return obs["poses"][a, :3] + np.array([0.0, 0.0, 0.02 + 0.02])

        return [
            *self.pick(rng, a, "A", order=4, grasp_dz=0.0, descend_speed=(0.08, 0.14)),
            *self.place(rng, "A", on_b, carry_z=TABLE_Z + 0.15, lower_speed=(0.07, 0.12)),
            # Over the tower of A on B first: a low diagonal approach to C can knock A off; and
            # C is grasped with the hand across the direction to the tower when it stands close.
            *self.pick(
                rng,
                c,
                "C",
                order=4,
                grasp_dz=0.0,
                approach_z=TABLE_Z + 0.16,
                descend_speed=(0.10, 0.16),
                avoid=lambda obs: obs["poses"][b, :3],
            ),
            *self.place(rng, "C", on_a, carry_z=TABLE_Z + 0.19, lower_speed=(0.07, 0.12)),
        ]


class CanExpert(PickPlaceExpert):
    """Can: top-down grasp of the upright can at any heading (it is round), carry it over the
    target bin at a safe height, lower it into its cell, release, retreat."""

    version = "can-1"
    tasks = ("Can",)

    def task_plan(self, rng):
        can, goal = entity_row(self.env, "can"), entity_row(self.env, "goal")
        rs = self.env.robosuite_env
        obj = rs.objects[rs.object_id]
        bottom = -float(obj.bottom_offset[2])  # can origin over its bottom
        drop = float(rng.uniform(0.01, 0.025))
        # A point of the cell a little towards the robot: the cell centre is at the edge of the
        # Panda's reach (the cell is about 0.10 x 0.12 m).
        cell = rng.uniform(-0.04, -0.015, 2)

        def in_cell(obs, mem):
            return obs["poses"][goal, :3] + np.array([cell[0], cell[1], bottom + drop])

        return [
            *self.pick(rng, can, "can", order=0, grasp_dz=float(rng.uniform(0.0, 0.015))),
            *self.place(rng, "can", in_cell, hover=(0.08, 0.12), release_dz=(0.0, 0.01), carry_z=1.02),
        ]


class SquareExpert(PickPlaceExpert):
    """Square: grasp the nut's handle across its width (two headings), carry the nut over the
    peg with its square hole turned to the nearest of the peg's four alignments, lower it onto
    the peg top, release (it slides down), retreat."""

    version = "square-1"
    tasks = ("Square",)
    #: Handle centre in the nut frame (m), and peg half height (m), from robosuite's models.
    HANDLE_X = 0.054
    PEG_HALF_HEIGHT = 0.1

    def task_plan(self, rng):
        nut, peg = entity_row(self.env, "nut"), entity_row(self.env, "peg")
        hx = self.HANDLE_X + float(rng.uniform(-0.008, 0.008))
        above_peg = float(rng.uniform(0.015, 0.03))

        def over_peg(obs, mem):
            return obs["poses"][peg, :3] + np.array([0.0, 0.0, self.PEG_HALF_HEIGHT + above_peg])

        choice = float(rng.random())

        def aligned(obs, mem):
            # Turn the held nut by d (about world z) so that its square hole lines up with the peg:
            # d = peg_yaw - nut_yaw + k pi/2. Among the k that keep the wrist turn small, keep those
            # with the handle (nut +x) not pointing away from the robot (the arm's reach ends
            # just beyond the peg), and pick one at random.
            if "nut_align" not in mem:
                r_eef = mem["nut_pose"][1]
                home = mem["psi_home"]
                turn = fr.wrap(fr.yaw_of(r_eef) - math.pi / 2 - home)
                lo, hi = fr.TURN_RANGE
                nut_yaw = fr.yaw_of(r_eef @ mem["nut"][1])
                d0 = fr.wrap(fr.yaw_of(obj_pose(obs, peg)[1]) - nut_yaw)
                cands = [d0 + k * math.pi / 2 for k in range(-4, 5)]
                ds = [d for d in cands if lo <= turn + d <= hi and abs(d) < 0.9 * math.pi]
                ds = [d for d in ds if math.cos(nut_yaw + d) < 0.3] or ds or [min(cands, key=abs)]
                mem["nut_align"] = fr.rz(ds[min(int(choice * len(ds)), len(ds) - 1)]) @ r_eef
            return mem["nut_align"]

        return [
            *self.pick(
                rng, nut, "nut", order=2, grasp_dz=0.0, grasp_offset=(hx, 0.0), yaw_offset=math.pi / 2
            ),
            *self.place(
                rng, "nut", over_peg, hover=(0.04, 0.07), release_dz=(0.0, 0.005), carry_z=1.05, rot=aligned
            ),
        ]


def aligned_eef_rotation(mem: dict, key: str, ref_yaw: float, order: int, choice: float) -> np.ndarray:
    """EEF orientation that turns the object held per ``mem[key]`` about world z so that its yaw
    equals ``ref_yaw`` modulo ``2 pi / order`` (a square peg or socket: order 4), choosing at
    random (``choice`` in [0, 1)) among the turns the wrist can reach (:data:`frames.TURN_RANGE`)."""
    r_eef = mem[key + "_pose"][1]
    turn = fr.wrap(fr.yaw_of(r_eef) - math.pi / 2 - mem["psi_home"])
    d0 = fr.wrap(ref_yaw - fr.yaw_of(r_eef @ mem[key][1]))
    step = 2 * math.pi / order
    cands = [d0 + k * step for k in range(-order, order + 1)]
    lo, hi = fr.TURN_RANGE
    ds = [d for d in cands if lo <= turn + d <= hi and abs(d) < 0.9 * math.pi] or [min(cands, key=abs)]
    return fr.rz(ds[min(int(choice * len(ds)), len(ds) - 1)]) @ r_eef


class ThreePieceAssemblyExpert(PickPlaceExpert):
    """ThreePieceAssembly: pick piece 1 (4 headings), turn it square to the base's socket, lower
    it in, release; then piece 2 into piece 1's socket the same way. A piece far from the robot
    is first relocated nearer (:meth:`PickPlaceExpert.relocate`).

    Version 2 adds the relocation: D2 places pieces up to 0.81 m from the robot base, where
    version 1's top-down pick straightened the arm into a pose it could not leave (10 of its
    13 failures in 100 D2 seeds). A relocation costs about 100 of the 500 steps, so version 2
    also ends a place's descent after 45 steps instead of 80: a piece that has not reached its
    seat by then is jammed on the socket's rim, and waiting does not free it (releasing it
    often does)."""

    version = "three_piece_assembly-2"
    tasks = ("ThreePieceAssembly_D0", "ThreePieceAssembly_D1", "ThreePieceAssembly_D2")
    #: Inserted height of piece 1's origin over the base's, and of piece 2's over piece 1's (m).
    PIECE1_OVER_BASE = 0.0175
    PIECE2_OVER_PIECE1 = 0.0225

    def task_plan(self, rng):
        base, p1, p2 = (entity_row(self.env, n) for n in ("base", "piece1", "piece2"))
        c1, c2 = float(rng.random()), float(rng.random())
        h1, h2 = float(rng.uniform(0.002, 0.006)), float(rng.uniform(0.002, 0.006))

        def into(row, height, extra):
            return lambda obs, mem: obs["poses"][row, :3] + np.array([0.0, 0.0, height + extra])

        def align(key, row, choice):
            def rot(obs, mem):
                if key + "_align" not in mem:
                    ref = fr.yaw_of(obj_pose(obs, row)[1])
                    mem[key + "_align"] = aligned_eef_rotation(mem, key, ref, 4, choice)
                return mem[key + "_align"]

            return rot

        return [
            *self.relocate(rng, p1, "p1", order=4, grasp_dz=-0.005, others=(base, p2)),
            *self.pick(rng, p1, "p1", order=4, grasp_dz=-0.005, xy_noise=0.002),
            *self.place(
                rng,
                "p1",
                into(base, self.PIECE1_OVER_BASE, h1),
                hover=(0.03, 0.06),
                release_dz=(0.0, 0.002),
                carry_z=TABLE_Z + 0.15,
                rot=align("p1", base, c1),
                lower_timeout=45,
            ),
            *self.relocate(rng, p2, "p2", order=4, grasp_dz=0.0, others=(base,)),
            *self.pick(rng, p2, "p2", order=4, grasp_dz=0.0, xy_noise=0.002),
            *self.place(
                rng,
                "p2",
                into(p1, self.PIECE2_OVER_PIECE1, h2),
                hover=(0.03, 0.06),
                release_dz=(0.0, 0.002),
                carry_z=TABLE_Z + 0.17,
                rot=align("p2", p1, c2),
                lower_timeout=45,
            ),
        ]


class ThreadingExpert(PickPlaceExpert):
    """Threading: grasp the needle's handle across its width (two headings), turn the needle
    parallel to the ring's axis (the direction of the two that the wrist reaches, at random),
    bring the tip in front of the ring, then push it along the axis into the ring's centre.

    With the needle held, its tip is at ``T_eef G t`` (``t = (TIP_X, 0, 0)`` in the needle frame);
    the EEF target that puts the tip at ``c - s u`` (``u`` the tip direction, ``s`` the stand-off)
    keeps the EEF orientation ``R`` and sets ``p_eef = c - s u - R (G_R t + G_p)``."""

    version = "threading-1"
    tasks = ("Threading_D0", "Threading_D1", "Threading_D2")
    TIP_X = 0.075
    HANDLE_X = -0.045

    def task_plan(self, rng):
        needle, ring = entity_row(self.env, "needle"), entity_row(self.env, "ring")
        choice = float(rng.random())
        standoff = float(rng.uniform(0.03, 0.05))
        hover = float(rng.uniform(0.03, 0.06))
        through = float(rng.uniform(-0.004, 0.002))
        tip = np.array([self.TIP_X, 0.0, 0.0])

        def rot(obs, mem):
            if "n_align" not in mem:
                ring_yaw = fr.yaw_of(obj_pose(obs, ring)[1])
                mem["n_align"] = aligned_eef_rotation(mem, "n", ring_yaw, 2, choice)
            return mem["n_align"]

        def eef_for_tip(obs, mem, s: float, dz: float = 0.0):
            r = rot(obs, mem)
            g_p, g_r = mem["n"]
            u = (r @ g_r)[:, 0]
            u = u - u[2] * np.array([0.0, 0.0, 1.0])
            u /= np.linalg.norm(u)
            if "ring_c" not in mem:
                mem["ring_c"] = obs["poses"][ring, :3].astype(np.float64)
            p = mem["ring_c"] - s * u - r @ (g_r @ tip + g_p)
            return p + np.array([0.0, 0.0, dz]), r

        return [
            *self.pick(
                rng,
                needle,
                "n",
                order=2,
                grasp_dz=0.0,
                xy_noise=0.002,
                grasp_offset=(self.HANDLE_X + float(rng.uniform(-0.008, 0.008)), 0.0),
                yaw_offset=-math.pi / 2,
            ),
            Waypoint(
                "carry",
                lambda o, m: eef_for_tip(o, m, standoff, hover),
                1.0,
                self._speed(rng),
                tol=0.01,
                timeout=120,
            ),
            Waypoint(
                "align",
                lambda o, m: eef_for_tip(o, m, standoff),
                1.0,
                self._speed(rng, 0.05, 0.1),
                tol=0.004,
                hold=int(rng.integers(1, 5)),
                timeout=80,
            ),
            Waypoint(
                "insert",
                lambda o, m: eef_for_tip(o, m, through),
                1.0,
                self._speed(rng, 0.03, 0.06),
                tol=0.003,
                hold=10,
                timeout=100,
            ),
        ]


class CoffeeExpert(PickPlaceExpert):
    """Coffee: pick the pod (any heading), drop it into the holder, then close the lid by pushing
    its back face with the closed fingers along its arc, from open (100 deg) to shut.

    Lid geometry in the holder frame ``H`` (the site at the holder floor's centre, x towards the
    machine front): the hinge is at ``h = (-HOLDER_OUTER_RADIUS, 0, HOLDER_DEPTH)``; a lid opened
    by ``a`` points along ``d(a) = (cos a, 0, sin a)`` from it, and its back face's normal is
    ``n(a) = (-sin a, 0, cos a)``. The push waypoints are ``h + r d(a) + delta n(a)`` for a
    decreasing sequence of ``a``.

    The open lid stands (leaning 10 deg back) just behind the holder's back rim, at ``x_H =
    -0.032``. The Panda hand is 0.20 m long along the finger axis (EEF x) and 0.064 m deep
    across it, so the pod is lowered with the finger axis along the holder's y axis (EEF
    heading ``psi = yaw_H`` or ``yaw_H + pi``, whichever the wrist reaches, at random): the hand
    then clears the lid by a few mm, while any other heading strikes it, tilts the pod in the
    cup and leaves the lid resting on the tilted pod. The pod is aimed a little forward of the
    holder axis (``+x_H``) for the same clearance, and carried there above the lid's top.
    """

    version = "coffee-2"
    tasks = ("Coffee_D0", "Coffee_D1", "Coffee_D2")
    HOLDER_OUTER_RADIUS = 0.032
    HOLDER_DEPTH = 0.032
    POD_HALF_HEIGHT = 0.0125

    def task_plan(self, rng):
        pod, holder = entity_row(self.env, "pod"), entity_row(self.env, "holder")
        drop = float(rng.uniform(0.01, 0.02))
        forward = float(rng.uniform(0.002, 0.005))
        radius = float(rng.uniform(0.04, 0.05))
        delta = float(rng.uniform(0.025, 0.035))
        choice = float(rng.random())
        angles = np.radians([105.0, 90.0, 70.0, 50.0, 30.0, 10.0, -5.0])

        def in_holder(obs, mem):
            p_h, r_h = obj_pose(obs, holder)
            return p_h + r_h @ np.array([forward, 0.0, self.POD_HALF_HEIGHT + drop])

        def clear_of_lid(obs, mem) -> np.ndarray:
            # Finger axis along holder y: psi in {yaw_H, yaw_H + pi} (a 2-fold choice).
            if "place_rot" not in mem:
                yaw_h = fr.yaw_of(obj_pose(obs, holder)[1])
                cur = fr.yaw_of(mem["pod_pose"][1]) - math.pi / 2
                home = mem["psi_home"]
                yaws = fr.symmetric_yaws(yaw_h, 2, home, home + fr.wrap(cur - home))
                mem["place_rot"] = fr.top_down(yaws[min(int(choice * len(yaws)), len(yaws) - 1)])
            return mem["place_rot"]

        def push_point(a: float, lift: float = 0.0):
            def target(obs, mem) -> Pose:
                p_h, r_h = obj_pose(obs, holder)
                hinge = np.array([-self.HOLDER_OUTER_RADIUS, 0.0, self.HOLDER_DEPTH])
                local = hinge + radius * np.array([math.cos(a), 0.0, math.sin(a)])
                local = local + delta * np.array([-math.sin(a), 0.0, math.cos(a)])
                return p_h + r_h @ local + np.array([0.0, 0.0, lift]), mem["place_rot"]

            return target

        pushes = [
            Waypoint(
                f"push{i}",
                push_point(a),
                1.0,
                self._speed(rng, 0.05, 0.1),
                tol=0.01,
                timeout=40,
            )
            for i, a in enumerate(angles[1:])
        ]
        # Over the open lid's top (1.02 m) with the held pod's bottom before moving sideways: a
        # diagonal climb from the pod to the holder hits the lid where its back faces the pod.
        safe_z = float(rng.uniform(1.07, 1.10))

        def rise(obs, mem) -> Pose:
            p, r = mem["pod_pose"]
            return np.array([p[0], p[1], safe_z]), r

        place = self.place(
            rng,
            "pod",
            in_holder,
            hover=(0.04, 0.07),
            release_dz=(0.0, 0.005),
            carry_z=safe_z,
            rot=clear_of_lid,
        )
        return [
            *self.pick(rng, pod, "pod", order=0, grasp_dz=0.0, xy_noise=0.002),
            Waypoint("rise", rise, 1.0, self._speed(rng), tol=0.02, timeout=60),
            *place,
            Waypoint("close_fingers", push_point(angles[0], 0.08), 1.0, self._speed(rng), tol=0.015),
            Waypoint("behind_lid", push_point(angles[0]), 1.0, self._speed(rng, 0.05, 0.1), tol=0.01),
            *pushes,
            Waypoint("leave", push_point(angles[-1], 0.08), 1.0, self._speed(rng, 0.1, 0.2), tol=0.02),
        ]
