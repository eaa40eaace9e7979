"""ToolHang expert: insert the hook frame into the stand's tube, then hang the tool on the hook.

The frames and sizes are in :mod:`.tool_hang_geometry`. Every move of a held object ``o`` is
written as a target pose ``T_o`` of the object and turned into the EEF target ``T_o G^-1``
(:meth:`~lerobot_actionflow.experts.skills.Grasp.eef_for`).

Plan:

1. **Frame.** Pick the frame by its grip from above, raise it upright (local ``z`` up) with its
   yaw chosen so that the EEF approach axis points away from the robot (the bar then points
   along world ``-y`` from its free end), lower its tip into the tube to 2-5 mm above the base
   plate with an integral correction of the tip's position (:func:`servo_correction`), release,
   back off.
2. **Back to top-down.** Straight up while turning the hand half way back along the turn that
   raised the frame (:meth:`ToolHangExpert.frame_up`), then to the home heading.
3. **Tool.** Pick the tool by its grip from above with the fingers along its local ``y``, the
   one heading of the two for which the hanging pose keeps wrist joint 7 inside its range (the
   other needs it past its limit). Lift, turning back near the home heading.
4. **Hook.** The hole (19.6 mm between flats) cannot be pushed square along the bar: the bar
   and its stub stand 19.5 mm tall. Instead the ring is tilted ``tilt`` (64-70 deg) from the
   vertical about the horizontal axis across the bar, its far lip (``TOOL_LIP``) forward and
   up, the handle slanting down and out past the bar's end (:func:`ring_rotation`). The lip is
   carried above the stub beyond the bar's end, moved along the bar past the stub (``hook_a``,
   11.5-13.5 mm from the end) and lowered onto the bar. Still held, the tool is turned about
   the lip in three steps to ``end_tilt`` (30-38 deg; the near lip swings down under the bar)
   and slid along the bar to ``slide_a`` (18-22 mm: a lip left closer to the stub catches on it
   when the ring turns upright), then released: it swings down and hangs from the bar with a
   flat of the hole on it (its centre 6 mm below the bar's axis; the check allows 6.75 mm).
   The episode ends when the check passes, before the hand backs off.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import numpy as np

from lerobot_actionflow import rotations
from lerobot_actionflow.experts import frames as fr
from lerobot_actionflow.experts.base import Waypoint
from lerobot_actionflow.experts.pick_place import PickPlaceExpert
from lerobot_actionflow.experts.pose import Pose, token_pose
from lerobot_actionflow.experts.skills import Grasp, PickDraws, PickParams, speed
from lerobot_actionflow.experts.tool_hang_geometry import (
    BAR_END,
    BASE_TOP,
    FRAME_GRIP,
    FRAME_TIP,
    TOOL_LIP,
    TUBE_IN_STAND,
    TUBE_TOP,
    lip_rest_height,
    ring_rotation,
)
from lerobot_actionflow.schema import ENV_POSES


def servo_correction(c: np.ndarray, err: np.ndarray, gain: float, limit: float) -> np.ndarray:
    """Integral correction ``c <- clip(c + gain err, -limit, limit)`` of an EEF position target
    ``(3,)``, updated in place and returned.

    The arm settles a few mm (and 1-2 deg) off an absolute OSC target when it holds a long
    object sideways, which a 0.19 m lever turns into a centimetre at the frame's tip; adding the
    integrated error ``err`` (desired minus measured position of the object point that matters)
    to the target removes it. Integrated only for small errors (no wind-up while moving)."""
    if float(np.linalg.norm(err)) < 0.02:
        c += gain * err
        np.clip(c, -limit, limit, out=c)
    return c


#: The frame, by its grip, across it (two headings).
PICK_FRAME = PickParams(
    order=2, grasp_dz=0.0, xy_noise=0.002, grasp_offset=tuple(FRAME_GRIP), yaw_offset=-math.pi / 2
)
#: The tool: one heading only (fingers along tool +y): the other needs joint 7 past its limit
#: to hang the tool.
PICK_TOOL = PickParams(order=1, grasp_dz=0.0, xy_noise=0.002, descend_speed=(0.12, 0.18))


@dataclass(frozen=True)
class ToolHangDraws:
    """The random choices of a ToolHang episode (after the tempo), in the order of the fields.
    Heights in m over the world (``safe_z``) or the named reference; angles in rad."""

    safe_z: float  # travel height with a held object
    above_tube: float  # frame tip over the tube's top before the insertion
    tip_end: float  # frame tip over the base plate at the end of the insertion
    tilt: float  # ring tilt from the vertical while hooking (64-70 deg)
    home_x: float  # the hand's waypoint between frame and tool
    home_y: float
    mid_heading: float  # heading from home while the tool rises
    hook_a: float  # lip position along the bar from its end when hooked
    pre_a: float  # lip position before the bar's end (< 0: beyond it)
    over_h: float  # lip height over the bar's axis while moving over it
    rest_extra: float  # lip height over its resting height when lowered
    end_tilt: float  # ring tilt at the end of the swing (30-38 deg)
    slide_a: float  # lip position along the bar at the release
    slow: float  # speed of the precise moves (m/s)
    insert_speed: float
    pick_frame: PickDraws
    frame_rise_speed: float
    over_tube_speed: float
    align_hold: int
    frame_back_speed: float
    frame_up_speed: float
    home_speed: float
    home_turn_speed: float
    pick_tool: PickDraws
    tool_rise_speed: float
    tool_turn_speed: float
    tool_pre_speed: float
    tool_pre_hold: int
    tool_back_speed: float

    @classmethod
    def draw(cls, rng: np.random.Generator, tempo: float) -> ToolHangDraws:
        u, v = rng.uniform, partial(speed, rng, tempo)
        return cls(
            safe_z=float(u(1.12, 1.18)),
            above_tube=float(u(0.03, 0.05)),
            tip_end=float(u(0.002, 0.005)),
            tilt=float(u(math.radians(64.0), math.radians(70.0))),
            home_x=float(u(-0.12, -0.08)),
            home_y=float(u(-0.03, 0.03)),
            mid_heading=float(u(math.radians(-20.0), math.radians(10.0))),
            hook_a=float(u(0.0115, 0.0135)),
            pre_a=float(u(-0.025, -0.012)),
            over_h=float(u(0.027, 0.031)),
            rest_extra=float(u(0.0, 0.002)),
            end_tilt=float(u(math.radians(30.0), math.radians(38.0))),
            slide_a=float(u(0.018, 0.022)),
            slow=v(0.04, 0.07),
            insert_speed=v(0.06, 0.09),
            pick_frame=PickDraws.draw(rng, PICK_FRAME, tempo),
            frame_rise_speed=v(),
            over_tube_speed=v(),
            align_hold=int(rng.integers(6, 12)),
            frame_back_speed=v(0.1, 0.2),
            frame_up_speed=v(),
            home_speed=v(),
            home_turn_speed=v(),
            pick_tool=PickDraws.draw(rng, PICK_TOOL, tempo),
            tool_rise_speed=v(),
            tool_turn_speed=v(),
            tool_pre_speed=v(0.08, 0.12),
            tool_pre_hold=int(rng.integers(5, 9)),
            tool_back_speed=v(0.05, 0.1),
        )


class ToolHangExpert(PickPlaceExpert):
    """ToolHang (see the module docstring for the frames and the plan). :attr:`frame` and
    :attr:`tool` hold the grasps; :attr:`frame_corr` and :attr:`tool_corr` the integral
    corrections ``(3,)`` of the frame's tip and the tool's lip."""

    version = "tool_hang-2"
    tasks = ("ToolHang",)

    def task_plan(self, rng: np.random.Generator) -> list[Waypoint]:
        self.draws = d = ToolHangDraws.draw(rng, self.tempo)
        self.stand_row = self.entity_row("stand")
        self.frame, self.tool = Grasp(self.entity_row("frame")), Grasp(self.entity_row("tool"))
        self.frame_corr, self.tool_corr = np.zeros(3), np.zeros(3)
        self.home_xyz = np.array([d.home_x, d.home_y, d.safe_z])  # between frame and tool
        rest_h = lip_rest_height(d.tilt) + d.rest_extra
        # Turned about the lip in steps (the command interpolates the EEF pose, not the lip's).
        tilts = np.linspace(d.tilt, d.end_tilt, 4)[1:]
        # Targets with their arguments bound: tip_at(dz=...)(obs), lip_at(a=..., h=...)(obs).
        tip_at, lip_at = partial(partial, self.frame_tip_at), partial(partial, self.lip_at)
        return [
            *self.pick(self.frame, PICK_FRAME, d.pick_frame),
            Waypoint("frame_rise", self.frame_rise, 1.0, d.frame_rise_speed, tol=0.02, timeout=80),
            Waypoint(
                "frame_over_tube",
                tip_at(dz=TUBE_TOP + d.above_tube, servo=False),
                1.0,
                d.over_tube_speed,
                tol=0.015,
                rot_speed=1.0,
                timeout=150,
            ),
            Waypoint(
                "frame_align",
                tip_at(dz=TUBE_TOP + 0.01),
                1.0,
                d.slow,
                tol=0.02,
                hold=d.align_hold,
                timeout=60,
                track=True,
            ),
            Waypoint(
                "frame_insert",
                tip_at(dz=BASE_TOP + d.tip_end),
                1.0,
                d.insert_speed,
                tol=0.004,
                hold=3,
                timeout=75,
                track=True,
            ),
            Waypoint("frame_release", tip_at(dz=BASE_TOP + d.tip_end), -1.0, 0.1, tol=1.0, hold=8),
            Waypoint(
                "frame_back",
                partial(self.back_off, dist=0.08, up=0.02),
                -1.0,
                d.frame_back_speed,
                tol=0.02,
                timeout=60,
            ),
            # Straight up before heading for the tool: a slanted path sweeps the hand through the frame.
            Waypoint("frame_up", self.frame_up, -1.0, d.frame_up_speed, tol=0.03, rot_speed=2.0, timeout=60),
            Waypoint("home", self.home, -1.0, d.home_speed, tol=0.05, rot_speed=2.0, timeout=30),
            Waypoint(
                "home_turn",
                self.home_turn,
                -1.0,
                d.home_turn_speed,
                tol=0.05,
                rot_speed=2.0,
                hold=12,
                timeout=30,
            ),
            *self.pick(self.tool, PICK_TOOL, d.pick_tool),
            Waypoint(
                "tool_rise", self.tool_rise, 1.0, d.tool_rise_speed, tol=0.02, rot_speed=1.5, timeout=80
            ),
            Waypoint(
                "tool_turn",
                lip_at(a=d.pre_a - 0.03, h=0.10, servo=False),
                1.0,
                d.tool_turn_speed,
                tol=0.03,
                rot_speed=1.0,
                timeout=100,
            ),
            Waypoint(
                "tool_pre",
                lip_at(a=d.pre_a, h=d.over_h),
                1.0,
                d.tool_pre_speed,
                tol=0.006,
                hold=d.tool_pre_hold,
                timeout=60,
                track=True,
            ),
            Waypoint(
                "tool_over",
                lip_at(a=d.hook_a, h=d.over_h),
                1.0,
                d.slow,
                tol=0.006,
                hold=3,
                timeout=40,
                track=True,
            ),
            Waypoint(
                "tool_down",
                lip_at(a=d.hook_a, h=rest_h),
                1.0,
                d.slow,
                tol=0.006,
                hold=2,
                timeout=40,
                track=True,
            ),
            *[
                Waypoint(
                    f"tool_swing{i}",
                    lip_at(a=d.hook_a, h=lip_rest_height(psi) + 0.001, psi=psi),
                    1.0,
                    0.05,
                    rot_speed=0.5,
                    tol=0.008,
                    timeout=30,
                    track=True,
                )
                for i, psi in enumerate(tilts)
            ],
            Waypoint(
                "tool_slide",
                lip_at(a=d.slide_a, h=lip_rest_height(d.end_tilt) + 0.001, psi=d.end_tilt),
                1.0,
                d.slow,
                tol=0.006,
                timeout=30,
                track=True,
            ),
            Waypoint(
                "tool_release",
                lip_at(a=d.slide_a, h=lip_rest_height(d.end_tilt), psi=d.end_tilt),
                -1.0,
                0.1,
                tol=1.0,
                hold=8,
            ),
            Waypoint(
                "tool_back",
                partial(self.back_off, dist=0.1, up=0.0),
                -1.0,
                d.tool_back_speed,
                tol=0.02,
                timeout=80,
            ),
        ]

    # -------------------------------------------------------------- frame
    def frame_upright(self) -> np.ndarray:
        """Upright frame orientation (local z up) whose grasp leaves the EEF approach axis
        pointing away from the robot (+x): ``R_f = Rz(a)``, EEF z ``= R_f G_r^T e_z``, whose
        heading is ``a + atan2(v_y, v_x)`` for ``v = G_r^T e_z``."""
        v = self.frame.in_hand.r[2, :]  # G_r^T e_z: the EEF approach axis in frame coordinates
        a = -math.atan2(v[1], v[0]) if abs(v[0]) + abs(v[1]) > 1e-6 else 0.0
        return rotations.yaw_matrix(a)

    def frame_tip_at(self, obs: dict, dz: float, servo: bool = True) -> Pose:
        """EEF pose with the upright frame's tip on the tube's axis, ``dz`` over the stand's
        origin; with ``servo``, plus :attr:`frame_corr`, integrated while the tip is above the
        tube (inside it the rod pivots about the tube's mouth: moving the hand one way moves the
        tip the other, and a wound-up correction jams the rod a centimetre above the floor)."""
        r_f = self.frame_upright()
        stand = token_pose(obs, self.stand_row)
        q = stand.apply(TUBE_IN_STAND)  # the tube's axis
        stand_z = stand.p[2]
        q[2] = stand_z + dz
        t = self.frame.eef_for(Pose(r_f, q - r_f @ FRAME_TIP))
        if not servo:
            return t
        tip = token_pose(obs, self.frame.row).apply(FRAME_TIP)
        err = q - tip
        err[2] = 0.0  # the depth is set by contact with the tube's bottom
        if tip[2] > stand_z + TUBE_TOP:
            servo_correction(self.frame_corr, err, 0.15, 0.025)
        return Pose(t.r, t.p + self.frame_corr)

    def frame_rise(self, obs: dict) -> Pose:
        p = obs[ENV_POSES][0, :3]
        return Pose(self.frame.eef.r, np.array([p[0], p[1], self.draws.safe_z]))

    def back_off(self, obs: dict, dist: float, up: float) -> Pose:
        """``dist`` back along the EEF approach axis from where it is, ``up`` higher."""
        eef = token_pose(obs, 0)
        return Pose(eef.r, eef.p - dist * eef.r[:, 2] + np.array([0.0, 0.0, up]))

    def frame_up(self, obs: dict) -> Pose:
        """Straight up, turning the hand half way back along the path it took to raise the
        frame: the direct turn to top-down is close to 180 deg and its geodesic may go the other
        way round, into the wrist's joint limits."""
        r_g = self.frame.eef.r
        r_u = self.frame_upright() @ self.frame.in_hand.r.T
        r_mid = r_u @ rotations.axis_angle_to_matrix(0.5 * rotations.matrix_to_axis_angle(r_u.T @ r_g))
        p = obs[ENV_POSES][0, :3]
        return Pose(r_mid, np.array([p[0], p[1], self.draws.safe_z]))

    def home(self, obs: dict) -> Pose:
        return Pose(self.frame.eef.r, self.home_xyz)

    def home_turn(self, obs: dict) -> Pose:
        return Pose(fr.top_down(self.home_heading(obs)), self.home_xyz)

    # -------------------------------------------------------------- tool
    def tool_rise(self, obs: dict) -> Pose:
        """Up to ``safe_z``, turning back near the home heading: the hanging pose is then a
        geodesic turn away that keeps wrist joint 7 inside its range."""
        p = self.tool.eef.p
        return Pose(
            fr.top_down(self.home_heading(obs) + self.draws.mid_heading),
            np.array([p[0], p[1], self.draws.safe_z]),
        )

    def bar(self, obs: dict) -> tuple[np.ndarray, np.ndarray]:
        """Bar end (world) and the horizontal unit vector from it along the bar towards the rod."""
        frame = token_pose(obs, self.frame.row)
        end = frame.apply(BAR_END)
        u = frame.p - end
        u[2] = 0.0
        return end, u / np.linalg.norm(u)

    def lip_at(self, obs: dict, a: float, h: float, psi: float | None = None, servo: bool = True) -> Pose:
        """EEF pose with the ring's far lip ``a`` along the bar from its end, ``h`` above the
        bar's axis, the ring tilted ``psi`` (default ``tilt``) (:func:`ring_rotation`); with
        ``servo``, plus :attr:`tool_corr`, integrated only once the command has arrived (the
        error of a lip still on its way winds it up into an overshoot along the bar)."""
        end, u = self.bar(obs)
        r_t = ring_rotation(u, self.draws.tilt if psi is None else psi)
        q = end + a * u + np.array([0.0, 0.0, h])
        t = self.tool.eef_for(Pose(r_t, q - r_t @ TOOL_LIP))
        if not servo:
            return t
        cmd = self.state.cmd
        if cmd is not None and float(np.linalg.norm(cmd.p - (t.p + self.tool_corr))) < 1e-3:
            lip = token_pose(obs, self.tool.row).apply(TOOL_LIP)
            servo_correction(self.tool_corr, q - lip, 0.15, 0.02)
        return Pose(t.r, t.p + self.tool_corr)
