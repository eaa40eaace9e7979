"""A robomimic demo (:class:`~lerobot_actionflow.data.robomimic.SourceDemo`) as schema arrays.

Frames and maths (world frame throughout; rotations are matrices ``R``, ``Exp`` is the
axis-angle exponential of :func:`~lerobot_actionflow.rotations.axis_angle_to_matrix`):

- EEF token: position ``p_t`` = ``robot0_eef_pos`` (the grip site), orientation
  ``R_t = R_hand,t R_HAND_TO_SITE``: robosuite's ``robot0_eef_quat`` is the hand body's
  orientation and the grip site is turned from it by -90 deg about the hand's z axis.
- Object tokens: the stored poses, quaternions made ``w >= 0``.
- Arm targets ``(R*_t, p*_t)`` by action mode (robosuite's OSC_POSE):

  - ``delta``: ``p* = p_t + s_p clip(a[:3], -1, 1)``,
    ``R* = Exp(s_r clip(a[3:6], -1, 1)) R_t``: the rotation delta is an axis-angle vector in the
    world frame applied on the left, and ``(s_p, s_r)`` are the controller's
    :class:`~lerobot_actionflow.data.robomimic.DeltaScales`. This is the goal the controller
    computes at step ``t`` from the pose it reads then ("achieved" goal update).
  - ``absolute``: ``p* = a[:3]``, ``R* = Exp(a[3:6])`` (world frame, grip site orientation).
  - ``next_pose``: ``(R*_t, p*_t) = (R_{t+1}, p_{t+1})``; the last step repeats its own pose.

- Gripper command: ``clip(a[6], -1, 1)`` (-1 open, +1 closed, as robosuite).

Output (:mod:`lerobot_actionflow.schema`), float32: ``observation.poses`` ``(T, N, 7)``,
``observation.state`` ``(T, 11)`` = ``[pose9(R_t, p_t), gripper_qpos]``,
``observation.environment_state`` ``(T, 9 (N - 1))`` = the objects' pose9, concatenated,
``action`` ``(T, 10)`` = ``[pose9(R*_t, p*_t), gripper command]``.
"""

from __future__ import annotations

import numpy as np

from lerobot_actionflow.data.robomimic import DeltaScales, SourceDemo
from lerobot_actionflow.rotations import (
    axis_angle_to_matrix,
    pose7_to_rp,
    quaternion_to_matrix,
    rp_to_pose7,
    rp_to_pose9,
)
from lerobot_actionflow.schema import ACTION_KEY, ENV_STATE_KEY, POSES_KEY, STATE_KEY

#: Grip-site orientation in the hand body's frame, ``R_site = R_hand @ R_HAND_TO_SITE``: a
#: rotation by -90 deg about the hand's z axis (robosuite 1.5.2's Panda gripper).
R_HAND_TO_SITE = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def eef_rotation(hand_quat: np.ndarray) -> np.ndarray:
    """Grip-site rotations ``(T, 3, 3)`` from hand-body quaternions ``(T, 4)`` ``(w, x, y, z)``."""
    return quaternion_to_matrix(hand_quat) @ R_HAND_TO_SITE


def arm_targets(
    actions: np.ndarray, r: np.ndarray, p: np.ndarray, mode: str, scales: DeltaScales
) -> tuple[np.ndarray, np.ndarray]:
    """Absolute EEF targets ``(R* (T, 3, 3), p* (T, 3))`` of the arm actions ``(T, 7)`` taken at
    EEF poses ``(r, p)``, by ``mode`` (module docstring)."""
    if mode == "delta":
        c = np.clip(actions[:, :6], -1.0, 1.0)
        return axis_angle_to_matrix(scales.rotation * c[:, 3:6]) @ r, p + scales.position * c[:, :3]
    if mode == "absolute":
        return axis_angle_to_matrix(actions[:, 3:6]), actions[:, :3].copy()
    if mode == "next_pose":
        nxt = np.r_[1 : len(p), len(p) - 1]
        return r[nxt], p[nxt]
    raise ValueError(f"unknown action mode {mode!r}")


def schema_arrays(demo: SourceDemo, mode: str, scales: DeltaScales) -> dict[str, np.ndarray]:
    """The schema's arrays of one demo, keyed by feature (module docstring)."""
    r_eef, p_eef = eef_rotation(demo.hand_quat), demo.eef_pos
    r_obj, p_obj = pose7_to_rp(demo.object_poses)  # (T, N - 1, 3, 3), (T, N - 1, 3)
    poses = rp_to_pose7(
        np.concatenate((r_eef[:, None], r_obj), axis=1), np.concatenate((p_eef[:, None], p_obj), axis=1)
    )
    state = np.concatenate((rp_to_pose9(r_eef, p_eef), demo.gripper_qpos), axis=-1)
    env_state = rp_to_pose9(r_obj, p_obj).reshape(len(p_eef), -1)
    r_tgt, p_tgt = arm_targets(demo.actions, r_eef, p_eef, mode, scales)
    action = np.concatenate((rp_to_pose9(r_tgt, p_tgt), np.clip(demo.actions[:, 6:7], -1.0, 1.0)), axis=-1)
    return {
        POSES_KEY: poses.astype(np.float32),
        STATE_KEY: state.astype(np.float32),
        ENV_STATE_KEY: env_state.astype(np.float32),
        ACTION_KEY: action.astype(np.float32),
    }
