"""Robomimic's four single-arm tasks (robosuite's own environments) as pose-token tasks.

- **Lift** (robosuite ``Lift``): tokens cube. Success: the cube's centre is more than 0.04 m
  above the table top.
- **Can** (``PickPlaceCan``): tokens can, goal (centre of the can's cell of the target bin).
  Success: the can is inside its cell of the target bin and the EEF is away from it.
- **Square** (``NutAssemblySquare``): tokens nut, peg (the square peg). Success: the nut is
  within 0.03 m (x and y) of the peg, less than 0.05 m over the table, and the EEF is away.
- **ToolHang** (``ToolHang``): tokens stand, frame, tool. Success: the frame is inserted in the
  stand and the tool hangs on the frame's hook, released.

The success check is robosuite's ``_check_success()`` of each env. "EEF away" is robosuite's
``1 - tanh(10 d) < 0.6``, i.e. the gripper site more than :data:`EEF_AWAY_M` = atanh(0.4) / 10
(about 0.042 m) from the object's centre; it does not check that the gripper has opened.
Episode lengths follow robomimic's evaluation horizons.
"""

from __future__ import annotations

import numpy as np

from lerobot_actionflow.envs.tasks import Entity, TaskSpec, register_task

#: The gripper-to-object distance (m) beyond which robosuite's Can and Square success checks
#: count the gripper as away: ``1 - tanh(10 d) < 0.6``.
EEF_AWAY_M = float(np.arctanh(0.4) / 10.0)


def _holds(env, obj) -> bool:
    """robosuite's grasp check: both fingers' pads touch ``obj`` (a MujocoObject or its geoms)."""
    return bool(env._check_grasp(gripper=env.robots[0].gripper, object_geoms=obj))


def lift_subgoals(env) -> dict[str, bool]:
    """Cube grasped, cube lifted (success)."""
    return {"cube_grasped": _holds(env, env.cube), "cube_lifted": bool(env._check_success())}


def can_subgoals(env) -> dict[str, bool]:
    """Can grasped; can inside its cell of the target bin (robosuite's ``not_in_bin``: over the
    cell, below 0.1 m above the bin floor); placed there with the gripper away (success)."""
    can = env.objects[env.object_id]
    pos = env.sim.data.body_xpos[env.obj_body_id[can.name]]
    return {
        "can_grasped": _holds(env, can),
        "can_in_cell": not env.not_in_bin(pos, env.object_id),
        "can_placed": bool(env._check_success()),
    }


def square_subgoals(env) -> dict[str, bool]:
    """Nut grasped; nut around the peg (robosuite's ``on_peg``); placed there with the gripper
    away (success)."""
    nut = env.nuts[env.nut_id]
    pos = env.sim.data.body_xpos[env.obj_body_id[nut.name]]
    return {
        "nut_grasped": _holds(env, nut),
        "nut_on_peg": bool(env.on_peg(pos, env.nut_id)),
        "nut_placed": bool(env._check_success()),
    }


def tool_hang_subgoals(env) -> dict[str, bool]:
    """Frame inserted in the stand, tool hung on the frame (both at once: success)."""
    return {
        "frame_assembled": bool(env._check_frame_assembled()),
        "tool_on_frame": bool(env._check_tool_on_frame()),
    }


def can_goal_pose(env) -> tuple[np.ndarray, np.ndarray]:
    """Centre of the can's cell in bin 2 (at the bin floor height), identity orientation."""
    pos = np.asarray(env.target_bin_placements[env.object_id], dtype=np.float64)
    return pos, np.array([1.0, 0.0, 0.0, 0.0])


LIFT = register_task(
    TaskSpec(
        name="Lift",
        env_class="robosuite.environments.manipulation.lift:Lift",
        subgoals="lerobot_actionflow.envs.robomimic_tasks:lift_subgoals",
        entities=(Entity("cube", body="cube_main", doc="the red cube, half size 0.02 m"),),
        episode_length=400,
        description="Lift the red cube off the table.",
        success="the cube's centre is more than 0.04 m above the table top",
    )
)

CAN = register_task(
    TaskSpec(
        name="Can",
        env_class="robosuite.environments.manipulation.pick_place:PickPlaceCan",
        subgoals="lerobot_actionflow.envs.robomimic_tasks:can_subgoals",
        entities=(
            Entity("can", body="Can_main", doc="the can"),
            Entity(
                "goal",
                pose_fn="lerobot_actionflow.envs.robomimic_tasks:can_goal_pose",
                doc="centre of the can's cell in the target bin (fixed), identity orientation",
            ),
        ),
        episode_length=400,
        description="Pick up the can and place it in its cell of the right bin.",
        success="the can is inside its cell of the target bin (below 0.1 m over the bin floor) "
        f"and the gripper is more than about {EEF_AWAY_M:.3f} m away from it",
        workspace_low=(-0.30, -0.55, 0.78),
        workspace_high=(0.40, 0.55, 1.40),
        # The target bin is part of the arena and robosuite's check uses its fixed position.
        scene_transform=False,
        # The bins arena has no side camera and no table: the bins are the support surfaces, and
        # the target bin's cell markers are visual-only bodies (no real sensor would see them).
        point_cloud_cameras=("agentview", "birdview"),
        point_cloud_removed=(
            "bin1",
            "bin2",
            *(f"Visual{o}_main" for o in ("Bread", "Can", "Cereal", "Milk")),
        ),
    )
)

SQUARE = register_task(
    TaskSpec(
        name="Square",
        env_class="robosuite.environments.manipulation.nut_assembly:NutAssemblySquare",
        subgoals="lerobot_actionflow.envs.robomimic_tasks:square_subgoals",
        entities=(
            Entity("nut", body="SquareNut_main", doc="the square nut"),
            Entity("peg", body="peg1", doc="the square peg (fixed to the table)"),
        ),
        episode_length=400,
        description="Pick up the square nut and place it onto the square peg.",
        success="the nut's centre is within 0.03 m (x and y) of the square peg, less than 0.05 m "
        f"above the table top, and the gripper is more than about {EEF_AWAY_M:.3f} m away from it",
        fixtures=("peg1", "peg2"),
    )
)

TOOL_HANG = register_task(
    TaskSpec(
        name="ToolHang",
        env_class="robosuite.environments.manipulation.tool_hang:ToolHang",
        subgoals="lerobot_actionflow.envs.robomimic_tasks:tool_hang_subgoals",
        entities=(
            # The same reference points as robosuite's own ToolHang observations.
            Entity("stand", geom="stand_base", doc="the stand's base plate"),
            Entity("frame", site="frame_intersection_site", doc="the corner of the L-shaped hook frame"),
            Entity("tool", body="tool_root", doc="the tool with a ring-shaped hole"),
        ),
        episode_length=700,
        description="Insert the hook frame into the stand, then hang the tool on the hook.",
        success="the stand is upright, the frame's end is inserted in the stand between its walls, "
        "and the tool's hole is on the hook, touching it, inserted along it, and not touched by the gripper",
        workspace_high=(0.40, 0.45, 1.45),
    )
)
