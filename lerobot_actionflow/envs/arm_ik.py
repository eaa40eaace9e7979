"""Inverse kinematics of the arm: put the end-effector site at a world pose, kinematics only.

Damped least squares on the arm joints ``q`` (the gripper and every other joint stay put). With
the site's world pose ``(R, p)``, the target ``(R*, p*)`` and the site Jacobian ``J = [J_p; J_r]``
``(6, n_arm)`` (world frame, arm columns only), each iteration takes

    e  = [p* - p ;  Log(R* R^T)]               (6,)  position error, rotation error as axis-angle
    dq = J^T (J J^T + lambda I_6)^-1 e         (n_arm,)
    q <- clip(q + dq, q_low, q_high)           (the joints' limits)

until ``|e_p| < 1e-4`` m and ``|e_r| < 1e-3`` rad. Only ``mj_kinematics`` and ``mj_comPos``
run between iterations (no dynamics); at the end the arm's joint velocities are zeroed and
``mj_forward`` brings the rest of the data (contacts, sensors) up to date.
"""

from __future__ import annotations

import mujoco
import numpy as np

from lerobot_actionflow.rotations import matrix_to_axis_angle

#: Position and rotation tolerances (metres, radians) and the damping ``lambda``.
POS_TOL = 1e-4
ROT_TOL = 1e-3
DAMPING = 1e-4


class ArmIK:
    """Damped least-squares IK of one site over a set of hinge joints.

    Args:
        model, data: the MuJoCo model and data (``data.qpos`` is edited in place).
        site: id of the site to place (the end-effector).
        joints: ids of the arm's joints (each one qpos and one dof).
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, site: int, joints) -> None:
        self._model, self._data, self._site = model, data, int(site)
        joints = np.asarray(joints, dtype=np.int64)
        self._qpos = model.jnt_qposadr[joints].astype(np.int64)
        self._dof = model.jnt_dofadr[joints].astype(np.int64)
        self._low, self._high = model.jnt_range[joints].T

    def solve(self, target_r: np.ndarray, target_p: np.ndarray, iters: int = 200) -> None:
        """Move the arm so that the site's world pose is ``(target_r (3, 3), target_p (3,))``.

        Raises:
            RuntimeError: the tolerances were not met within ``iters`` iterations.
        """
        m, d, site = self._model, self._data, self._site
        jacp, jacr = np.empty((3, m.nv)), np.empty((3, m.nv))
        for _ in range(iters):
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            r = d.site_xmat[site].reshape(3, 3)
            err = np.concatenate([target_p - d.site_xpos[site], matrix_to_axis_angle(target_r @ r.T)])
            if np.linalg.norm(err[:3]) < POS_TOL and np.linalg.norm(err[3:]) < ROT_TOL:
                break
            mujoco.mj_jacSite(m, d, jacp, jacr, site)
            jac = np.concatenate([jacp[:, self._dof], jacr[:, self._dof]])
            dq = jac.T @ np.linalg.solve(jac @ jac.T + DAMPING * np.eye(6), err)
            d.qpos[self._qpos] = np.clip(d.qpos[self._qpos] + dq, self._low, self._high)
        else:
            raise RuntimeError(f"arm IK did not reach the target EEF pose (error {err})")
        d.qvel[self._dof] = 0.0
        mujoco.mj_forward(m, d)
