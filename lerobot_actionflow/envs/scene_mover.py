"""Applying a :class:`~lerobot_actionflow.envs.scene_transform.SceneTransform` to a MuJoCo scene.

A drawn transform ``(yaw, tx, ty)`` is the rigid motion ``(r, p)`` (:func:`planar_motion`)

    x' = r x + p,   r = Rz(yaw),   p = c + t - Rz(yaw) c,

with ``c = (cx, cy, 0)`` the task's pivot and ``t = (tx, ty, 0)``; it rotates about the vertical
axis through the pivot and keeps heights. :class:`SceneMover` applies it, in the world frame, to

* every free joint of the model (the task's objects; the arm is mounted, it has none):
  position ``x' = r x + p``, orientation ``R' = r R``;
* every fixture body (a jointless body of the layout, e.g. a peg): its body offset relative to
  its parent, which must be unrotated, is set so that its world pose moves the same way.

Fixtures are edited in the *model*: :meth:`SceneMover.restore_fixtures` puts them back before
the next reset. Drawing is conditioned on the layout staying on the table
(:meth:`SceneMover.sample`). Moving the arm's initial end-effector pose (``move_robot``) is the
env's job, by :class:`~lerobot_actionflow.envs.arm_ik.ArmIK` towards ``(r, p) T_eef``.
"""

from __future__ import annotations

import mujoco
import numpy as np

from lerobot_actionflow.envs.scene_transform import SceneTransform
from lerobot_actionflow.envs.tasks import TaskSpec
from lerobot_actionflow.rotations import apply, matrix_to_quaternion, quaternion_to_matrix, yaw_matrix

#: Every entity token must stay this far (metres) inside the table's edges.
TABLE_MARGIN = 0.02


def planar_motion(
    yaw: float, shift_xy: tuple[float, float], pivot_xy: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """The rigid transform ``(r (3, 3), p (3,))`` of ``x' = Rz(yaw) (x - c) + c + t``."""
    r = yaw_matrix(yaw)
    c = np.array([pivot_xy[0], pivot_xy[1], 0.0])
    return r, c + np.array([shift_xy[0], shift_xy[1], 0.0]) - r @ c


class SceneMover:
    """Moves a task's layout (free objects and fixtures) in a MuJoCo model and data.

    Args:
        model, data: the MuJoCo model and data.
        spec: the task (its fixtures, pivot and entity names).
        table_centre_xy, table_half_xy: the table top's centre and half sizes (world xy).
    """

    def __init__(
        self, model: mujoco.MjModel, data: mujoco.MjData, spec: TaskSpec, table_centre_xy, table_half_xy
    ):
        self._model, self._data, self._spec = model, data, spec
        self._table_centre = np.asarray(table_centre_xy, dtype=np.float64)[:2]
        self._table_half = np.asarray(table_half_xy, dtype=np.float64)[:2] - TABLE_MARGIN
        free = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
        adr = model.jnt_qposadr[free].astype(np.int64)[:, None]
        self._free_pos, self._free_quat = adr + np.arange(3), adr + np.arange(3, 7)  # (k, 3), (k, 4)
        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name) for name in spec.fixtures]
        for name, bid in zip(spec.fixtures, ids, strict=True):
            if bid < 0:
                raise RuntimeError(f"task {spec.name}: no fixture body {name!r}")
        self._fixtures = np.asarray(ids, dtype=np.int64)
        self._fixture_parents = model.body_parentid[self._fixtures]
        self._fixture_pos = model.body_pos[self._fixtures].copy()  # (f, 3) as built
        self._fixture_quat = model.body_quat[self._fixtures].copy()  # (f, 4)

    def restore_fixtures(self) -> None:
        """Put the fixtures back where the model had them."""
        self._model.body_pos[self._fixtures] = self._fixture_pos
        self._model.body_quat[self._fixtures] = self._fixture_quat

    def sample(
        self, transform: SceneTransform, rng: np.random.Generator, points: np.ndarray, tries: int = 100
    ) -> tuple[np.ndarray, np.ndarray]:
        """Draw a transform that keeps every entity token over the table; its ``(r, p)``.

        ``points`` ``(N - 1, 3)`` are the entity tokens' world positions. A transform with
        ranges is redrawn (up to ``tries`` times) while it would move a token off the table, so
        the layout is conditioned on staying on it.

        Raises:
            ValueError: no draw kept every token on the table (always so for a constant
                transform that does not), naming the tokens that left it.
        """
        for _ in range(tries):
            yaw, tx, ty = transform.sample(rng)
            r, p = planar_motion(yaw, (tx, ty), self._spec.pivot_xy)
            xy = apply(r, p, points)[:, :2]
            off = np.flatnonzero((np.abs(xy - self._table_centre) > self._table_half).any(axis=1))
            if not len(off):
                return r, p
        names = [self._spec.entities[i].name for i in off]
        raise ValueError(
            f"scene transform {transform} moves {names} of {self._spec.name} off the table; use a "
            "smaller shift or yaw range for this task/variant"
        )

    def move(self, r: np.ndarray, p: np.ndarray) -> None:
        """Apply ``(r, p)`` to the free objects and the fixtures, then run ``mj_forward``."""
        m, d = self._model, self._data
        if len(self._free_pos):
            d.qpos[self._free_pos] = apply(r, p, d.qpos[self._free_pos])
            d.qpos[self._free_quat] = matrix_to_quaternion(r @ quaternion_to_matrix(d.qpos[self._free_quat]))
        if len(self._fixtures):
            if not np.allclose(d.xquat[self._fixture_parents], [1.0, 0.0, 0.0, 0.0]):
                raise RuntimeError("scene transform: fixtures must have an unrotated parent body")
            parent_pos = d.xpos[self._fixture_parents]
            m.body_pos[self._fixtures] = apply(r, p, parent_pos + self._fixture_pos) - parent_pos
            m.body_quat[self._fixtures] = matrix_to_quaternion(r @ quaternion_to_matrix(self._fixture_quat))
        mujoco.mj_forward(m, d)
