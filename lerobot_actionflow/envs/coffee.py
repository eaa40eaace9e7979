"""Coffee: put the pod into the machine's pod holder and close the hinged lid.

The machine is built here from robosuite boxes (Mimicgen's uses meshes; nothing of it is used):
a robosuite ``CompositeBodyObject`` with a free joint made of

- the **body** (one ``CompositeObject``): a base plate, a column at the back (local -x), an arm
  and, in front of the column, the **pod holder**: a cup of 12 boxes (inner radius 0.026 m,
  0.032 m deep) on a floor plate whose top is 0.12 m above the table; the site
  ``coffee_machine_body_holder`` marks the centre of the holder's floor;
- the **lid**: a 0.07 x 0.07 x 0.008 m plate on a hinge (axis local y) at the holder's back
  rim; closed (hinge angle 0) it lies on the rim, and it opens up to 100 deg (joint limit),
  where it rests. Every episode starts with the lid fully open.

The **pod** is a cylinder (radius 0.02 m, height 0.025 m) that fits in the holder below its rim.

Success: the lid's hinge angle is below 15 deg and the pod is inside the holder: its centre
within 0.012 m (xy) of the holder's axis and within 0.01 m of its resting height on the floor.

Placement variants (yaw in degrees; the machine's front, local +x, faces the robot at yaw 180):

| variant | machine x / y / yaw                  | pod x / y                        |
| ------- | ------------------------------------ | -------------------------------- |
| D0      | +-0.02 / [0.12, 0.15] / 180 +- 10    | [-0.10, 0.00] / [-0.20, -0.10]   |
| D1      | +-0.05 / [0.10, 0.20] / 180 +- 30    | [-0.15, 0.05] / [-0.25, -0.08]   |
| D2      | +-0.05 / [0.10, 0.20] / [120, 210]   | [-0.20, 0.10] / [-0.30, -0.08]   |

D2 follows the machine ranges Mimicgen documents for Coffee_D2; D0 and D1 are ours.
"""

from __future__ import annotations

import math

import numpy as np
from robosuite.models.objects import CompositeBodyObject, CylinderObject

from lerobot_actionflow.envs.materials import box_composite, textured
from lerobot_actionflow.envs.tabletop import Placement, TabletopTask
from lerobot_actionflow.rotations import axis_angle_to_matrix, matrix_to_quaternion

_D = math.radians
HOLDER_INNER_RADIUS = 0.026
HOLDER_OUTER_RADIUS = 0.032
HOLDER_DEPTH = 0.032
HOLDER_FLOOR_Z = 0.12  # holder floor top over the machine's bottom
HOLDER_X = 0.045  # holder axis, local x
POD_RADIUS = 0.02
POD_HALF_HEIGHT = 0.0125
LID_OPEN = _D(100)
LID_CLOSED_BELOW = _D(15)
POD_XY_TOLERANCE = 0.012
POD_Z_TOLERANCE = 0.01
RING_SEGMENTS = 12

COFFEE_VARIANTS: dict[str, dict[str, Placement]] = {
    "D0": {
        "machine": Placement(x=(-0.02, 0.02), y=(0.12, 0.15), yaw=(math.pi - _D(10), math.pi + _D(10))),
        "pod": Placement(x=(-0.10, 0.0), y=(-0.20, -0.10), yaw=(0.0, 2 * math.pi)),
    },
    "D1": {
        "machine": Placement(x=(-0.05, 0.05), y=(0.10, 0.20), yaw=(math.pi - _D(30), math.pi + _D(30))),
        "pod": Placement(x=(-0.15, 0.05), y=(-0.25, -0.08), yaw=(0.0, 2 * math.pi)),
    },
    "D2": {
        "machine": Placement(x=(-0.05, 0.05), y=(0.10, 0.20), yaw=(_D(120), _D(210))),
        "pod": Placement(x=(-0.20, 0.10), y=(-0.30, -0.08), yaw=(0.0, 2 * math.pi)),
    },
}


def _machine_body(name: str):
    """The rigid part. Locations relative to its bounding-box centre; its bottom is at -half_z."""
    half_z = (HOLDER_FLOOR_Z + HOLDER_DEPTH) / 2
    z0 = -half_z  # the bottom, in the composite's frame
    sizes, locs, quats, names = [], [], [], []

    def add(nm, size, loc, quat=(1.0, 0.0, 0.0, 0.0)):
        names.append(nm)
        sizes.append(size)
        locs.append(loc)
        quats.append(list(quat))

    add("plate", (0.09, 0.07, 0.006), (0.0, 0.0, z0 + 0.006))
    col_h = HOLDER_FLOOR_Z + HOLDER_DEPTH - 0.012
    add("column", (0.02, 0.05, col_h / 2), (-0.065, 0.0, z0 + 0.012 + col_h / 2))
    arm_x0, arm_x1 = -0.045, HOLDER_X - HOLDER_OUTER_RADIUS + 0.002
    add(
        "arm",
        ((arm_x1 - arm_x0) / 2, 0.012, 0.008),
        ((arm_x0 + arm_x1) / 2, 0.0, z0 + HOLDER_FLOOR_Z - 0.008),
    )
    add(
        "floor",
        (HOLDER_OUTER_RADIUS, HOLDER_OUTER_RADIUS, 0.004),
        (HOLDER_X, 0.0, z0 + HOLDER_FLOOR_Z - 0.004),
    )
    r_mid = (HOLDER_INNER_RADIUS + HOLDER_OUTER_RADIUS) / 2
    half_t = r_mid * math.tan(math.pi / RING_SEGMENTS) * 1.05
    for k in range(RING_SEGMENTS):
        th = 2 * math.pi * k / RING_SEGMENTS
        # Local axes of a segment: x radial, y tangential (a rotation about z by th).
        add(
            f"cup{k}",
            ((HOLDER_OUTER_RADIUS - HOLDER_INNER_RADIUS) / 2, half_t, HOLDER_DEPTH / 2),
            (HOLDER_X + r_mid * math.cos(th), r_mid * math.sin(th), z0 + HOLDER_FLOOR_Z + HOLDER_DEPTH / 2),
            matrix_to_quaternion(axis_angle_to_matrix(np.array([0.0, 0.0, th]))).tolist(),
        )
    n = len(names)
    return box_composite(
        name,
        materials=[textured("SteelBrushed", f"{name}_steel"), textured("PlasterGray", f"{name}_plastic")],
        geom_materials=[0, 1, 1] + [0] * (n - 3),
        total_size=(0.09, 0.07, half_z),
        geom_types=["box"] * n,
        geom_sizes=sizes,
        geom_locations=locs,
        geom_quats=quats,
        geom_names=names,
        density=3000.0,
        locations_relative_to_center=True,
        joints=None,
        sites=[
            {
                "name": "holder",
                "pos": (HOLDER_X, 0.0, z0 + HOLDER_FLOOR_Z),
                "size": "0.002",
                "rgba": "0 1 0 1",
            }
        ],
    )


def make_machine(name: str = "coffee_machine") -> CompositeBodyObject:
    # Child names get the machine's prefix from robosuite: "coffee_machine_body_...", "..._lid_...".
    body = _machine_body("body")
    half_z = (HOLDER_FLOOR_Z + HOLDER_DEPTH) / 2
    lid_half = (0.035, 0.035, 0.004)
    lid = box_composite(
        "lid",
        materials=[textured("PlasterGray", "lid_plastic")],
        geom_materials=[0],
        total_size=lid_half,
        geom_types=["box"],
        geom_sizes=[lid_half],
        geom_locations=[(0.0, 0.0, 0.0)],
        geom_names=["plate"],
        density=300.0,
        locations_relative_to_center=True,
        joints=None,
    )
    hinge_x = HOLDER_X - HOLDER_OUTER_RADIUS  # the holder's back rim, local x
    rim_z = -half_z + HOLDER_FLOOR_Z + HOLDER_DEPTH
    # Closed: the lid's centre over the holder axis, resting on the rim; hinge at its back edge.
    lid_pos = (hinge_x + lid_half[0], 0.0, rim_z + lid_half[2])
    hinge = {
        "name": "hinge",
        "type": "hinge",
        "axis": "0 -1 0",  # positive angle lifts the lid's front edge (local +x) upward
        "pos": f"{-lid_half[0]} 0 {-lid_half[2]}",
        "limited": "true",
        "range": f"0 {LID_OPEN}",
        "damping": "0.005",
    }
    return CompositeBodyObject(
        name=name,
        objects=[body, lid],
        object_locations=[(0.0, 0.0, 0.0), lid_pos],
        object_parents=[None, body.root_body],
        body_joints={lid.root_body: [hinge]},
    )


def make_pod(name: str = "pod") -> CylinderObject:
    return CylinderObject(
        name=name,
        size=(POD_RADIUS, POD_HALF_HEIGHT),
        material=textured("Brass", f"{name}_brass"),
        rgba=None,
        density=500.0,
        friction=(1.0, 0.005, 0.0001),
    )


class Coffee(TabletopTask):
    """Pod into the holder, lid closed; ``variant`` in ``"D0"``, ``"D1"``, ``"D2"``."""

    VARIANTS = tuple(COFFEE_VARIANTS)

    def _build_objects(self):
        place = COFFEE_VARIANTS[self.variant]
        return {"machine": (make_machine(), place["machine"]), "pod": (make_pod(), place["pod"])}

    def _setup_references(self):
        super()._setup_references()
        names = [self.sim.model.joint_id2name(j) for j in range(self.sim.model.njnt)]
        hinge = next(
            n for n in names if n is not None and n.startswith("coffee_machine") and n.endswith("hinge")
        )
        self.lid_qpos_addr = self.sim.model.get_joint_qpos_addr(hinge)
        self.lid_qvel_addr = self.sim.model.get_joint_qvel_addr(hinge)

    def _reset_internal(self):
        super()._reset_internal()
        self.sim.data.qpos[self.lid_qpos_addr] = LID_OPEN
        self.sim.data.qvel[self.lid_qvel_addr] = 0.0

    @property
    def lid_angle(self) -> float:
        """The lid's hinge angle in radians: 0 closed, up to 100 deg open."""
        return float(self.sim.data.qpos[self.lid_qpos_addr])

    def pod_in_holder(self) -> bool:
        holder = self.site_pos("coffee_machine_body_holder")
        pod = self.body_pos("pod")
        return bool(
            np.linalg.norm(pod[:2] - holder[:2]) < POD_XY_TOLERANCE
            and abs(pod[2] - (holder[2] + POD_HALF_HEIGHT)) < POD_Z_TOLERANCE
        )

    def lid_closed(self) -> bool:
        return self.lid_angle < LID_CLOSED_BELOW

    def _check_success(self) -> bool:
        return self.lid_closed() and self.pod_in_holder()


def subgoals(env: Coffee) -> dict[str, bool]:
    """Pod grasped, pod in the holder, lid closed (the last two at once: success)."""
    return {
        "pod_grasped": env.grasped("pod"),
        "pod_in_holder": env.pod_in_holder(),
        "lid_closed": env.lid_closed(),
    }
