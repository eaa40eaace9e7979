"""Constructed success states, one per task family: object poses set through MuJoCo data
(kinematics only, no physics; MugHang's then simulated, as its check wants a settled mug), far
from the gripper, so that each task's check must say yes."""

from __future__ import annotations

import mujoco
import numpy as np

from lerobot_actionflow.rotations import matrix_to_quaternion, quaternion_to_matrix

Z = np.array([0.0, 0.0, 1.0])
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def _frame(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Orthonormal basis (columns) with first axis along a and second in the (a, b) plane."""
    a = a / np.linalg.norm(a)
    b = b - a.dot(b) * a
    b = b / np.linalg.norm(b)
    return np.stack([a, b, np.cross(a, b)], axis=1)


def _body_local(env, body: str, point: np.ndarray) -> np.ndarray:
    m, d = env._model, env._data
    b = m.body(body).id
    return d.xmat[b].reshape(3, 3).T @ (point - d.xpos[b])


def lift(env) -> None:
    env.set_entity_pose("cube", [0.0, 0.0, 0.8 + 0.10], IDENTITY)


def can(env) -> None:
    goal = env.get_observation()["poses"][2, :3]
    env.set_entity_pose("can", goal + np.array([0.0, 0.0, 0.05]), IDENTITY)


def square(env) -> None:
    peg = env.get_observation()["poses"][2, :3]
    env.set_entity_pose("nut", [peg[0], peg[1], 0.82 + 0.02], IDENTITY)


def stack_three(env) -> None:
    top = 0.8
    env.set_entity_pose("cubeB", [0.0, 0.0, top + 0.025], IDENTITY)
    # 1 mm overlaps, so that MuJoCo reports the contacts.
    env.set_entity_pose("cubeA", [0.0, 0.0, top + 0.05 + 0.02 - 0.001], IDENTITY)
    env.set_entity_pose("cubeC", [0.003, 0.0, top + 0.05 + 0.04 + 0.02 - 0.002], IDENTITY)


def tool_hang(env) -> None:
    """Frame post upright through the stand's mount (between its walls, tip near the base),
    tool's hole threaded on the hook, halfway along it, resting on it."""
    rs, d = env.robosuite_env, env._data
    site = {k: d.site_xpos[i].copy() for k, i in rs.obj_site_id.items()}
    lm, li, lh, lt = (
        _body_local(env, "frame_root", site[k])
        for k in ("frame_mount_site", "frame_intersection_site", "frame_hang_site", "frame_tip_site")
    )
    r_frame = _frame(Z, np.array([1.0, 0.0, 0.0])) @ _frame(li - lm, lh - li).T
    base = d.geom_xpos[rs.obj_geom_id["stand_base"]].copy()
    walls = np.mean([d.geom_xpos[rs.obj_geom_id[f"stand_wall_{i}"]] for i in range(4)], axis=0)
    tip_target = np.array([walls[0], walls[1], base[2] + 0.01])
    env.set_body_pose("frame_root", tip_target - r_frame @ lt, matrix_to_quaternion(r_frame))

    hang = d.site_xpos[rs.obj_site_id["frame_hang_site"]].copy()
    inter = d.site_xpos[rs.obj_site_id["frame_intersection_site"]].copy()
    hook = (inter - hang) / np.linalg.norm(inter - hang)
    tool_r = d.xmat[env._model.body("tool_root").id].reshape(3, 3)
    hole_axis = tool_r.T @ d.xmat[env._model.body("tool_hole1_root").id].reshape(3, 3)[:, 2]
    lc = _body_local(env, "tool_root", d.site_xpos[rs.obj_site_id["tool_hole1_center"]].copy())
    r_tool = _frame(hook, -Z) @ _frame(hole_axis, -lc).T
    centre = hang + 0.5 * (inter - hang) - 0.0063 * Z  # the hole's top rests on the hook
    env.set_body_pose("tool_root", centre - r_tool @ lc, matrix_to_quaternion(r_tool))


def threading(env, along_axis: float = 0.0) -> None:
    """Needle aligned with the ring's axis, its tip ``along_axis`` metres past the ring centre."""
    ring = env.get_observation()["poses"][2].astype(np.float64)
    r = quaternion_to_matrix(ring[3:])
    tip_local = np.array([0.075, 0.0, 0.0])
    env.set_entity_pose("needle", ring[:3] + along_axis * r[:, 0] - r @ tip_local, matrix_to_quaternion(r))


def three_piece_assembly(env) -> None:
    """Both pieces inserted, aligned with the base (1 mm above their resting heights)."""
    base = env.get_observation()["poses"][1].astype(np.float64)
    env.set_entity_pose("piece1", base[:3] + np.array([0.0, 0.0, 0.0175 + 0.001]), base[3:])
    env.set_entity_pose("piece2", base[:3] + np.array([0.0, 0.0, 0.0175 + 0.0225 + 0.002]), base[3:])


def set_lid(env, angle: float) -> None:
    rs = env.robosuite_env
    env._data.qpos[rs.lid_qpos_addr] = angle
    mujoco.mj_forward(env._model, env._data)


def coffee(env) -> None:
    """Pod resting in the holder (1 mm up), lid closed."""
    holder = env.get_observation()["poses"][2].astype(np.float64)
    env.set_entity_pose("pod", holder[:3] + np.array([0.0, 0.0, 0.0125 + 0.001]), IDENTITY)
    set_lid(env, 0.0)


def mug_hang(env, depth: float = 0.07, steps: int = 60) -> None:
    """Mug upright, threaded on the peg ``depth`` along it from its root with the handle's top
    bar 2 mm over it, then simulated (the arm holding still, open) until it hangs settled: the
    check counts still steps, so a kinematic pose alone is never a success."""
    from lerobot_actionflow.envs import mug_hang as mh

    rs = env.robosuite_env
    root, u = rs.peg_frame()
    along = np.array([u[0], u[1], 0.0]) / np.linalg.norm(u[:2])
    r = np.stack([np.cross(along, Z), along, Z], axis=1)  # mug x radial, y along the peg, z up
    centre = root + depth * u + (mh.HOLE_HEIGHT / 2 - mh.PEG_RADIUS - 0.002) * Z
    env.set_body_pose("mug_root", centre - r @ np.array([mh.HANDLE_X, 0.0, 0.0]), matrix_to_quaternion(r))
    pos, mat = env.eef_pose()
    hold = np.concatenate([pos, mat[:, 0], mat[:, 1], [-1.0]]).astype(np.float32)
    for _ in range(steps):
        if env.step(hold)[4]["is_success"]:
            return


def construct_success(env) -> None:
    """Put ``env`` (a :class:`PoseTokenEnv`) into a success state of its task."""
    name = env.task
    if name.startswith("StackThree"):
        return stack_three(env)
    if name.startswith("Threading"):
        return threading(env)
    if name.startswith("ThreePieceAssembly"):
        return three_piece_assembly(env)
    if name.startswith("Coffee"):
        return coffee(env)
    if name.startswith("MugHang"):
        return mug_hang(env)
    return {"Lift": lift, "Can": can, "Square": square, "ToolHang": tool_hang}[name](env)
