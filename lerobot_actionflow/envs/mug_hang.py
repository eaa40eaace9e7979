"""MugHang: hang a mug by its handle on the angled peg of a hanger, built from robosuite primitives.

Objects (robosuite ``CompositeObject`` s, free joints):

- **mug**: a solid cylinder (radius 0.03 m, height 0.09 m; body frame at its centre, z up) with a
  handle on its local +x side: a rectangular loop of three boxes in the mug's x-z plane whose
  opening is 0.035 m (radial, x) by 0.05 m (vertical, z), its centre (site ``mug_handle``) at
  ``(HANDLE_X, 0, 0)``; the opening's normal is the mug's local y axis. A dark disc marks the
  opening on top (visual only). Its free joint is lightly damped (``MUG_DAMPING``), so that
  a mug hanging on the round peg stops rocking.
- **hanger**: a heavy 0.14 x 0.14 m base plate, a vertical post (radius 0.01 m) and, from the
  post's top (``PEG_ROOT_Z`` = 0.20 m over the table), a peg (radius 0.006 m, length 0.12 m)
  pointing along the hanger's local +x and rising ``PEG_ANGLE`` = 30 deg above the horizontal.
  The site ``hanger_peg`` sits at the peg's root with its x axis along the peg (towards the
  tip), y the hanger's local y.

Success (:meth:`MugHang._check_success`): the mug hangs on the peg and has settled:

- the peg passes through the handle's opening: the peg's axis crosses the opening's plane
  within the opening (0.035 x 0.05 m) and within the peg's length;
- the mug touches the peg, and touches neither the table nor the gripper (released);
- the mug's speed has stayed under ``SETTLED_SPEED`` (0.03 m/s) and its angular speed under
  ``SETTLED_SPIN`` (0.5 rad/s), with the above, for ``SETTLED_STEPS`` (5) consecutive control
  steps (0.25 s): counted once per control step, after the physics.

Placement variants (table-top frame; yaw 180 deg points the peg at the robot, along -x; mug yaw
0 puts the handle on the far side, +x):

| variant | hanger x / y / yaw                                  | mug x / y / yaw                       |
| ------- | --------------------------------------------------- | ------------------------------------- |
| D0      | 0.15 / 0.0 / 180 (fixed)                            | [-0.12, -0.04] / +-0.06 / 0 +- 20 deg |
| Moved   | [0.05, 0.15] / +-[0.20, 0.25] / 180 +- 35 deg        | as D0                                 |

D0 is the training set: the hanger in one place. In ``Moved`` the hanger stands on the left or
the right of the table (one draw, probability 1/2 each: the whole layout is mirrored about the
table's x axis, which maps both objects, and the mug's distribution, onto themselves) and is
turned by up to 35 deg either way.
"""

from __future__ import annotations

import math

import numpy as np
from robosuite.models.objects import CompositeObject

from lerobot_actionflow.envs.materials import box_composite, textured
from lerobot_actionflow.envs.tabletop import Placement, TabletopTask
from lerobot_actionflow.rotations import axis_angle_to_matrix, matrix_to_quaternion

_D = math.radians

MUG_RADIUS = 0.03
MUG_HALF_HEIGHT = 0.045
#: The handle's opening: radial width (mug x) and height (mug z), and its bars' thickness.
HOLE_WIDTH = 0.035
HOLE_HEIGHT = 0.05
HANDLE_BAR = 0.008
HANDLE_HALF_Y = 0.006
#: Centre of the handle's opening in the mug frame, on its x axis.
HANDLE_X = MUG_RADIUS + HOLE_WIDTH / 2

HANGER_HALF_BASE = 0.07
HANGER_BASE_HALF_Z = 0.008
POST_RADIUS = 0.01
PEG_ROOT_Z = 0.20  # over the hanger's bottom (the table)
PEG_RADIUS = 0.006
PEG_LENGTH = 0.12
PEG_ANGLE = _D(30.0)

#: Damping (N s m / N m s) of the mug's free joint: a stand-in for the rolling friction that
#: settles a real mug on a peg (MuJoCo's default contacts roll without loss, and the hanging
#: mug would rock on the round peg for ever). It damps the swing on the peg in about 0.5 s and
#: slows a falling mug by under 2 %/s.
MUG_DAMPING = 0.002

SETTLED_SPEED = 0.03
SETTLED_SPIN = 0.5
SETTLED_STEPS = 5

_MUG = Placement(x=(-0.12, -0.04), y=(-0.06, 0.06), yaw=(-_D(20), _D(20)))
MUG_HANG_VARIANTS: dict[str, dict[str, Placement]] = {
    "D0": {
        "hanger": Placement(x=(0.15, 0.15), y=(0.0, 0.0), yaw=(math.pi, math.pi)),
        "mug": _MUG,
    },
    "Moved": {
        "hanger": Placement(x=(0.05, 0.15), y=(0.20, 0.25), yaw=(math.pi - _D(35), math.pi + _D(35))),
        "mug": _MUG,
    },
}
#: Variants whose layout is mirrored about the table's x axis with probability 1/2.
MIRRORED_VARIANTS = ("Moved",)


def _quat_about(axis: str, angle: float) -> list[float]:
    """Scalar-first quaternion of a rotation by ``angle`` about the coordinate axis ``axis``."""
    return matrix_to_quaternion(axis_angle_to_matrix(angle * np.eye(3)["xyz".index(axis)])).tolist()


def make_mug(name: str = "mug") -> CompositeObject:
    """The mug (module docstring); geoms ``body``, ``handle_top``, ``handle_bottom``,
    ``handle_outer`` and the visual ``coffee``; site ``handle`` at the opening's centre."""
    bar_x0 = MUG_RADIUS - 0.004  # the bars start inside the body
    bar_x1 = MUG_RADIUS + HOLE_WIDTH + HANDLE_BAR
    bar_half = ((bar_x1 - bar_x0) / 2, HANDLE_HALF_Y, HANDLE_BAR / 2)
    bar_z = HOLE_HEIGHT / 2 + HANDLE_BAR / 2
    outer_x = MUG_RADIUS + HOLE_WIDTH + HANDLE_BAR / 2
    return box_composite(
        name,
        materials=[textured("Clay", f"{name}_clay"), textured("WoodDark", f"{name}_coffee")],
        geom_materials=[0, 0, 0, 0, 1],
        total_size=(bar_x1, MUG_RADIUS, MUG_HALF_HEIGHT),
        geom_types=["cylinder", "box", "box", "box", "cylinder"],
        geom_sizes=[
            (MUG_RADIUS, MUG_HALF_HEIGHT),
            bar_half,
            bar_half,
            (HANDLE_BAR / 2, HANDLE_HALF_Y, HOLE_HEIGHT / 2 + HANDLE_BAR),
            (MUG_RADIUS - 0.004, 0.0005),
        ],
        geom_locations=[
            (0.0, 0.0, 0.0),
            ((bar_x0 + bar_x1) / 2, 0.0, bar_z),
            ((bar_x0 + bar_x1) / 2, 0.0, -bar_z),
            (outer_x, 0.0, 0.0),
            (0.0, 0.0, MUG_HALF_HEIGHT),
        ],
        geom_names=["body", "handle_top", "handle_bottom", "handle_outer", "coffee"],
        density=500.0,
        obj_types=["all", "all", "all", "all", "visual"],
        locations_relative_to_center=True,
        joints=[{"type": "free", "damping": str(MUG_DAMPING)}],
        sites=[{"name": "handle", "pos": (HANDLE_X, 0, 0), "size": "0.002", "rgba": "0 1 0 0"}],
    )


def make_hanger(name: str = "hanger") -> CompositeObject:
    """The hanger (module docstring); geoms ``base``, ``post`` and ``peg``; site ``peg`` at the
    peg's root, x along the peg."""
    half_z = (PEG_ROOT_Z + PEG_LENGTH * math.sin(PEG_ANGLE)) / 2
    bottom = -half_z
    post_top = PEG_ROOT_Z + PEG_RADIUS  # the post covers the peg's root
    post_half = (post_top - 2 * HANGER_BASE_HALF_Z) / 2
    u = np.array([math.cos(PEG_ANGLE), 0.0, math.sin(PEG_ANGLE)])
    root = np.array([0.0, 0.0, bottom + PEG_ROOT_Z])
    peg_centre = root + 0.5 * PEG_LENGTH * u
    return box_composite(
        name,
        materials=[textured("WoodLight", f"{name}_light"), textured("WoodDark", f"{name}_dark")],
        geom_materials=[0, 1, 1],
        total_size=(HANGER_HALF_BASE, HANGER_HALF_BASE, half_z),
        geom_types=["box", "cylinder", "cylinder"],
        geom_sizes=[
            (HANGER_HALF_BASE, HANGER_HALF_BASE, HANGER_BASE_HALF_Z),
            (POST_RADIUS, post_half),
            (PEG_RADIUS, PEG_LENGTH / 2),
        ],
        geom_locations=[
            (0.0, 0.0, bottom + HANGER_BASE_HALF_Z),
            (0.0, 0.0, bottom + 2 * HANGER_BASE_HALF_Z + post_half),
            tuple(peg_centre),
        ],
        # A cylinder's axis is its local z: turned about y by 90 deg - angle onto the peg's direction.
        geom_quats=[[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], _quat_about("y", math.pi / 2 - PEG_ANGLE)],
        geom_names=["base", "post", "peg"],
        density=[10000.0, 2000.0, 2000.0],
        locations_relative_to_center=True,
        sites=[
            {
                "name": "peg",
                "pos": tuple(root),
                "quat": " ".join(str(q) for q in _quat_about("y", -PEG_ANGLE)),
                "size": "0.002",
                "rgba": "0 1 0 0",
            }
        ],
    )


class MugHang(TabletopTask):
    """Hang the mug on the hanger's peg; ``variant`` in ``"D0"``, ``"Moved"``."""

    VARIANTS = tuple(MUG_HANG_VARIANTS)

    def _build_objects(self):
        place = MUG_HANG_VARIANTS[self.variant]
        return {"hanger": (make_hanger(), place["hanger"]), "mug": (make_mug(), place["mug"])}

    def _setup_references(self):
        super()._setup_references()
        m = self.sim.model
        self.peg_site_id = m.site_name2id("hanger_peg")
        self.handle_site_id = m.site_name2id("mug_handle")
        self.peg_geom = "hanger_peg"
        mug = self.objects["mug"]
        self.mug_qvel_addr = m.get_joint_qvel_addr(mug.joints[0])
        self.mug_qpos_addr = m.get_joint_qpos_addr(mug.joints[0])
        self.hanger_qpos_addr = m.get_joint_qpos_addr(self.objects["hanger"].joints[0])

    def _reset_internal(self):
        super()._reset_internal()
        if not self.deterministic_reset and self.variant in MIRRORED_VARIANTS and self.rng.random() < 0.5:
            # Mirror about the table's x axis: y -> -y, yaw -> -yaw (both objects are symmetric
            # about their local x-z planes, so the mirror image is the same object).
            for lo, _ in (self.hanger_qpos_addr, self.mug_qpos_addr):
                q = self.sim.data.qpos
                q[lo + 1] = 2 * self.table_offset[1] - q[lo + 1]
                w, x, y, z = q[lo + 3 : lo + 7]
                q[lo + 3 : lo + 7] = (w, -x, y, -z)
            self.sim.forward()
        self.settled_steps = 0

    # -------------------------------------------------------------- geometry
    def peg_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """World position ``(3,)`` of the peg's root and its unit axis ``(3,)`` towards the tip."""
        d = self.sim.data
        return np.array(d.site_xpos[self.peg_site_id]), np.array(
            d.site_xmat[self.peg_site_id].reshape(3, 3)[:, 0]
        )

    def handle_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """World position ``(3,)`` of the handle opening's centre and the mug's rotation ``(3, 3)``
        (columns: radial x, opening normal y, up z)."""
        d = self.sim.data
        return np.array(d.site_xpos[self.handle_site_id]), np.array(
            d.xmat[self.obj_body_ids["mug"]].reshape(3, 3)
        )

    def peg_through_handle(self) -> bool:
        """Whether the peg's axis crosses the handle's opening plane inside the opening and
        within the peg's length (the bars keep the peg out of the plane elsewhere)."""
        root, u = self.peg_frame()
        centre, r = self.handle_frame()
        normal = r[:, 1]
        un = float(u @ normal)
        if abs(un) < 0.5:  # the peg lies more than 60 deg off the opening's normal
            return False
        t = float((centre - root) @ normal) / un
        off = root + t * u - centre
        return bool(
            0.0 <= t <= PEG_LENGTH
            and abs(float(off @ r[:, 0])) <= HOLE_WIDTH / 2
            and abs(float(off @ r[:, 2])) <= HOLE_HEIGHT / 2
        )

    def hanging(self) -> bool:
        """Threaded on the peg, touching it, and touching neither the table nor the gripper."""
        mug = self.objects["mug"]
        return (
            self.peg_through_handle()
            and self.check_contact(mug, [self.peg_geom])
            and not self.check_contact(mug, ["table_collision"])
            and not any(self.check_contact(g, mug) for g in self.robots[0].gripper.values())
        )

    def mug_still(self) -> bool:
        v = self.sim.data.qvel[self.mug_qvel_addr[0] : self.mug_qvel_addr[1]]
        return bool(np.linalg.norm(v[:3]) < SETTLED_SPEED and np.linalg.norm(v[3:]) < SETTLED_SPIN)

    def _post_action(self, action):
        # Once per control step, after the physics: count the steps the mug has hung still.
        self.settled_steps = self.settled_steps + 1 if self.hanging() and self.mug_still() else 0
        return super()._post_action(action)

    def _check_success(self) -> bool:
        return self.settled_steps >= SETTLED_STEPS and self.hanging()


def subgoals(env: MugHang) -> dict[str, bool]:
    """Mug grasped, handle on the peg, hanging released, hanging still (success)."""
    return {
        "mug_grasped": env.grasped("mug"),
        "handle_on_peg": env.peg_through_handle(),
        "hanging": env.hanging(),
        "settled": env._check_success(),
    }
