"""The pose-token Gymnasium env: one robosuite task, observed as entity poses, driven by
absolute end-effector pose targets.

Observation (a dict; every pose in the world frame, the frame of robosuite's observations):

- ``poses`` float32 ``(N, 7)``: ``[x, y, z, qw, qx, qy, qz]`` per entity, row 0 the
  end-effector (robosuite's grip site, the point the arm controller tracks), rows 1.. the
  task's entities in :attr:`TaskSpec.entities` order. Quaternions are scalar-first with
  ``qw >= 0``. They are read from MuJoCo, which is scalar-first already, so no robosuite
  scalar-last quaternion is involved.
- ``agent_pos`` float32 ``(11,)``: EEF position (3), EEF rotation as 6D (first two columns of
  its rotation matrix, 6), gripper finger joint positions (2).
- ``environment_state`` float32 ``(9 (N-1),)``: per entity ``[pos (3), rot6d (6)]``.
- ``pixels`` (only with ``cameras``): ``{camera: uint8 (H, W, 3)}``, cameras ``"wrist"``
  (robosuite's ``robot0_eye_in_hand``), ``"agentview"`` or any other camera of the model.

Action float32 ``(10,)``: ``[x, y, z, rot6d (6), gripper]``, the absolute EEF target in the
world frame; gripper in ``[-1, 1]`` (-1 open, +1 closed; values outside are clipped). The
position is clipped to the task's workspace box (:attr:`TaskSpec.workspace_low` /
``workspace_high``). A wrong shape, a NaN/inf entry or a degenerate 6D rotation raises
``ValueError``. The target goes to robosuite's OSC_POSE controller in absolute world mode
(:mod:`lerobot_actionflow.envs.controller`) as position + axis-angle.

Reward is 1.0 on a success step, else 0.0; ``info["is_success"]`` carries the task's check;
the episode terminates on success (``terminate_on_success``) and is truncated by Gymnasium's
``TimeLimit`` at the task's episode length when made through ``gym.make``.

Rendering uses ``mujoco.Renderer`` on the env's own model and data (robosuite's renderer is
off): visual geoms only (group 1), no multisample anti-aliasing. Without a GPU (software EGL)
a frame costs tens of milliseconds, more than a physics step: request images only when needed.

Seeding: ``reset(seed=s)`` re-seeds, in place, the one numpy generator through which robosuite
samples robot initialisation noise and object placements, and the generator of the scene
transform; the same seed gives the same initial state, and with the same actions the same
episode, in any env instance (what robosuite draws at construction is seeded too).
"""

from __future__ import annotations

import atexit
import math
import weakref
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np

from lerobot_actionflow.envs import rotations as rot
from lerobot_actionflow.envs.controller import absolute_pose_controller_config
from lerobot_actionflow.envs.scene_transform import SceneTransform, planar_transform_points, yaw_quat
from lerobot_actionflow.envs.tasks import CONTROL_FREQ, TaskSpec, get_task

#: Our camera names -> robosuite's.
CAMERA_ALIASES = {"wrist": "robot0_eye_in_hand", "agentview": "agentview"}

ACTION_DIM = 10
AGENT_POS_DIM = 11
#: Indices of the 6D rotation (first two columns) in a row-major flattened 3x3 matrix.
_ROT6D_FROM_FLAT = np.array([0, 3, 6, 1, 4, 7])

#: Envs holding renderers, so that their GL contexts are released before MuJoCo's EGL display
#: is terminated at exit (that atexit hook is registered when MuJoCo's GL module is imported, by
#: the first renderer; ours is registered after it, so it runs first).
_LIVE_ENVS: weakref.WeakSet = weakref.WeakSet()
_EXIT_HOOK = []


def _close_renderers_at_exit() -> None:
    for env in list(_LIVE_ENVS):
        env.close_renderers()


class PoseTokenEnv(gym.Env):
    """A robosuite task with pose-token observations and absolute EEF pose actions.

    Args:
        task: a registered task name (``"Lift"``, ``"StackThree_D1"``, ...).
        cameras: cameras to return under ``observation["pixels"]`` (empty: no images).
        image_height, image_width: size of those images.
        render_mode: ``"rgb_array"`` (``render()`` returns ``uint8 (H, W, 3)``).
        render_camera, render_height, render_width: the view ``render()`` returns.
        scene_transform: a :class:`SceneTransform` (or a dict of its fields) applied at every
            reset; ``None`` for the task's own placement distribution.
        terminate_on_success: end the episode at the first success step.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": CONTROL_FREQ}

    def __init__(
        self,
        task: str = "Lift",
        cameras: tuple[str, ...] | list[str] = (),
        image_height: int = 84,
        image_width: int = 84,
        render_mode: str | None = "rgb_array",
        render_camera: str = "agentview",
        render_height: int = 256,
        render_width: int = 256,
        scene_transform: SceneTransform | dict | None = None,
        terminate_on_success: bool = True,
    ):
        super().__init__()
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be 'rgb_array' or None, got {render_mode!r}")
        self.spec_task: TaskSpec = get_task(task)
        self.task = self.spec_task.name
        self.task_description = self.spec_task.description
        self.render_mode = render_mode
        self.terminate_on_success = terminate_on_success
        self.cameras = tuple(cameras.split(",") if isinstance(cameras, str) else cameras)
        self.cameras = tuple(c.strip() for c in self.cameras if c.strip())
        self.image_size = (int(image_height), int(image_width))
        self.render_camera = render_camera
        self.render_size = (int(render_height), int(render_width))
        self.scene_transform = SceneTransform.coerce(scene_transform)
        if self.scene_transform is not None and not self.spec_task.scene_transform:
            raise ValueError(f"task {self.task} does not support a scene transform (fixed goal in the arena)")
        self._ws_low = np.asarray(self.spec_task.workspace_low, dtype=np.float64)
        self._ws_high = np.asarray(self.spec_task.workspace_high, dtype=np.float64)

        self._env = make_robosuite_env(self.spec_task)
        self._sim = self._env.sim
        self._model: mujoco.MjModel = self._sim.model._model
        self._data: mujoco.MjData = self._sim.data._data
        self._setup_references()

        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}
        # No multisample anti-aliasing offscreen: it doubles the cost of a frame on a CPU (software
        # EGL) renderer for a barely visible difference at these sizes.
        self._model.vis.quality.offsamples = 0
        self._scene_option = mujoco.MjvOption()
        self._scene_option.geomgroup[0] = 0  # robosuite: group 0 collision, group 1 visual
        for cam in (*self.cameras, self.render_camera):
            self._camera_id(cam)  # fail early on an unknown camera

        n = self.spec_task.num_tokens
        obs_spaces: dict[str, gym.Space] = {
            "poses": gym.spaces.Box(-np.inf, np.inf, (n, 7), np.float32),
            "agent_pos": gym.spaces.Box(-np.inf, np.inf, (AGENT_POS_DIM,), np.float32),
            "environment_state": gym.spaces.Box(-np.inf, np.inf, (9 * (n - 1),), np.float32),
        }
        if self.cameras:
            obs_spaces["pixels"] = gym.spaces.Dict(
                {c: gym.spaces.Box(0, 255, (*self.image_size, 3), np.uint8) for c in self.cameras}
            )
        self.observation_space = gym.spaces.Dict(obs_spaces)
        low = np.concatenate([self._ws_low, -np.ones(7)]).astype(np.float32)
        high = np.concatenate([self._ws_high, np.ones(7)]).astype(np.float32)
        self.action_space = gym.spaces.Box(low, high, (ACTION_DIM,), np.float32)
        self._last_success = False

    # ------------------------------------------------------------------ set-up
    def _setup_references(self) -> None:
        robot = self._env.robots[0]
        self._robot = robot
        self._eef_site = int(robot.eef_site_id["right"])
        self._gripper_qpos = np.asarray(robot._ref_gripper_joint_pos_indexes["right"], dtype=np.int64)
        if self._gripper_qpos.shape != (2,):
            raise RuntimeError(f"expected 2 gripper joints, got {self._gripper_qpos.shape}")
        self._arm_qpos = np.asarray(robot._ref_joint_pos_indexes, dtype=np.int64)
        self._arm_dof = np.asarray(robot._ref_joint_vel_indexes, dtype=np.int64)
        # Token rows grouped by the kind of MuJoCo element they read (vectorised reads).
        kinds = {
            "body": mujoco.mjtObj.mjOBJ_BODY,
            "site": mujoco.mjtObj.mjOBJ_SITE,
            "geom": mujoco.mjtObj.mjOBJ_GEOM,
        }
        rows: dict[str, list[tuple[int, int]]] = {k: [] for k in kinds}
        self._virtual = []
        self._entity_body: dict[str, int] = {}
        for i, ent in enumerate(self.spec_task.entities):
            if ent.kind == "pose_fn":
                self._virtual.append((i + 1, ent.resolve_pose_fn()))
                continue
            ref = getattr(ent, ent.kind)
            eid = mujoco.mj_name2id(self._model, kinds[ent.kind], ref)
            if eid < 0:
                raise RuntimeError(f"task {self.task}: no {ent.kind} {ref!r} for entity {ent.name!r}")
            rows[ent.kind].append((i + 1, eid))
            body = {"body": eid, "site": None, "geom": None}[ent.kind]
            if body is None:
                body = (self._model.site_bodyid if ent.kind == "site" else self._model.geom_bodyid)[eid]
            self._entity_body[ent.name] = int(body)
        self._rows = {
            k: (np.array([r for r, _ in v], dtype=np.int64), np.array([e for _, e in v], dtype=np.int64))
            for k, v in rows.items()
            if v
        }
        # Free joints of everything but the robot: what a scene transform moves.
        self._free_qpos = [
            int(self._model.jnt_qposadr[j])
            for j in range(self._model.njnt)
            if self._model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE
        ]
        self._fixtures = []
        for name in self.spec_task.fixtures:
            bid = mujoco.mj_name2id(self._model, mujoco.mjtObj.mjOBJ_BODY, name)
            if bid < 0:
                raise RuntimeError(f"task {self.task}: no fixture body {name!r}")
            parent = self._model.body_parentid[bid]
            self._fixtures.append(
                (bid, parent, self._model.body_pos[bid].copy(), self._model.body_quat[bid].copy())
            )

    def _camera_id(self, camera: str) -> int:
        name = CAMERA_ALIASES.get(camera, camera)
        cid = mujoco.mj_name2id(self._model, mujoco.mjtObj.mjOBJ_CAMERA, name)
        if cid < 0:
            known = [self._model.camera(i).name for i in range(self._model.ncam)]
            raise ValueError(f"task {self.task} has no camera {camera!r}; known: {known} and 'wrist'")
        return cid

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if seed is not None:
            # robosuite's samplers and robot noise all hold a reference to env.rng: reseed it in place.
            self._env.rng.bit_generator.state = np.random.default_rng(seed).bit_generator.state
        self._restore_fixtures()
        self._env.reset()
        if self.scene_transform is not None and not self.scene_transform.is_identity:
            self._apply_scene_transform(*self._sample_transform_on_table())
        self._last_success = bool(self._env._check_success())
        return self._observe(), {"is_success": self._last_success}

    def step(self, action):
        # robosuite computes its sparse reward from ``_check_success()`` inside ``step`` (shaping off,
        # scale 1): it is positive exactly on success, so the check is not evaluated twice.
        _, rs_reward, _, _ = self._env.step(self.to_robosuite_action(action))
        success = bool(rs_reward > 0)
        self._last_success = success
        terminated = success and self.terminate_on_success
        return self._observe(), float(success), terminated, False, {"is_success": success}

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            return None
        return self.render_camera_image(self.render_camera, *self.render_size)

    def close_renderers(self) -> None:
        """Release the offscreen GL contexts (made again on the next render)."""
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()

    def close(self) -> None:
        self.close_renderers()
        if getattr(self, "_env", None) is not None:
            self._env.close()
            self._env = None

    # ------------------------------------------------------------------ actions
    def to_robosuite_action(self, action) -> np.ndarray:
        """Validate a 10-D action and convert it to robosuite's ``[pos, axis-angle, gripper]``.

        Raises:
            ValueError: wrong shape, a non-finite entry, or a degenerate 6D rotation.
        """
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise ValueError(f"action must be a numeric array of shape ({ACTION_DIM},): {e}") from e
        if a.shape != (ACTION_DIM,):
            raise ValueError(
                f"action must have shape ({ACTION_DIM},) = [x, y, z, rot6d (6), gripper], got shape {a.shape}"
            )
        if not math.isfinite(a.sum()):  # one reduction; NaN/inf anywhere makes the sum non-finite
            bad = np.flatnonzero(~np.isfinite(a)).tolist()
            raise ValueError(f"action has non-finite (NaN/inf) entries at indices {bad}: {a.tolist()}")
        out = np.empty(7)
        out[:3] = np.minimum(np.maximum(a[:3], self._ws_low), self._ws_high)
        out[3:6] = rot.matrix_to_rotvec(rot.rot6d_to_matrix(a[3:9]))
        out[6] = min(max(a[9], -1.0), 1.0)
        return out

    # ------------------------------------------------------------------ observations
    def eef_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World position ``(3,)`` and rotation matrix ``(3, 3)`` of the end-effector."""
        return self._data.site_xpos[self._eef_site].copy(), self._data.site_xmat[self._eef_site].reshape(3, 3)

    def _observe(self) -> dict[str, Any]:
        d = self._data
        n = self.spec_task.num_tokens
        poses = np.empty((n, 7), dtype=np.float64)
        flat = np.empty((n, 9), dtype=np.float64)  # row-major rotation matrices
        poses[0, :3] = d.site_xpos[self._eef_site]
        flat[0] = d.site_xmat[self._eef_site]
        mujoco.mju_mat2Quat(poses[0, 3:], flat[0])
        if "body" in self._rows:
            rows, ids = self._rows["body"]
            poses[rows, :3] = d.xpos[ids]
            poses[rows, 3:] = d.xquat[ids]
            flat[rows] = d.xmat[ids]
        for kind, pos_arr, mat_arr in (
            ("site", d.site_xpos, d.site_xmat),
            ("geom", d.geom_xpos, d.geom_xmat),
        ):
            if kind in self._rows:
                rows, ids = self._rows[kind]
                poses[rows, :3] = pos_arr[ids]
                flat[rows] = mat_arr[ids]
                for r in rows:
                    mujoco.mju_mat2Quat(poses[r, 3:], flat[r])
        for row, fn in self._virtual:
            pos, quat = fn(self._env)
            poses[row, :3] = pos
            poses[row, 3:] = np.asarray(quat) / np.linalg.norm(quat)
            flat[row] = rot.quat_to_matrix(poses[row, 3:]).reshape(9)
        neg = poses[:, 3] < 0
        if neg.any():
            poses[neg, 3:] *= -1.0
        rot6d = flat[:, _ROT6D_FROM_FLAT]
        agent_pos = np.concatenate([poses[0, :3], rot6d[0], d.qpos[self._gripper_qpos]])
        env_state = np.concatenate([poses[1:, :3], rot6d[1:]], axis=-1).reshape(-1)
        obs: dict[str, Any] = {
            "poses": poses.astype(np.float32),
            "agent_pos": agent_pos.astype(np.float32),
            "environment_state": env_state.astype(np.float32),
        }
        if self.cameras:
            obs["pixels"] = {c: self.render_camera_image(c, *self.image_size) for c in self.cameras}
        return obs

    def render_camera_image(self, camera: str, height: int, width: int) -> np.ndarray:
        """RGB ``uint8 (height, width, 3)`` from a camera (alias or robosuite name)."""
        key = (height, width)
        renderer = self._renderers.get(key)
        if renderer is None:
            vis = self._model.vis.global_
            vis.offwidth, vis.offheight = max(vis.offwidth, width), max(vis.offheight, height)
            renderer = self._renderers[key] = mujoco.Renderer(self._model, height, width)
            _LIVE_ENVS.add(self)
            if not _EXIT_HOOK:
                _EXIT_HOOK.append(atexit.register(_close_renderers_at_exit))
        renderer.update_scene(self._data, camera=self._camera_id(camera), scene_option=self._scene_option)
        return renderer.render()

    # ------------------------------------------------------------------ state access
    @property
    def robosuite_env(self):
        """The wrapped robosuite environment (for experts, data conversion and tests)."""
        return self._env

    def is_success(self) -> bool:
        """The task's success check on the current simulator state."""
        return bool(self._env._check_success())

    def get_observation(self) -> dict[str, Any]:
        """The observation of the current simulator state (e.g. after editing it)."""
        return self._observe()

    def set_body_pose(self, body: str | int, pos, quat_wxyz) -> None:
        """Teleport a body with a free joint (name or id), zero its velocity, and run
        ``mj_forward`` (kinematics and contacts). For tests, experts and constructed states."""
        m, d = self._model, self._data
        bid = body if isinstance(body, int) else mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body)
        jnt = m.body_jntadr[bid] if bid >= 0 else -1
        if jnt < 0 or m.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_FREE:
            raise ValueError(f"body {body!r} of {self.task} has no free joint")
        adr, dof = m.jnt_qposadr[jnt], m.jnt_dofadr[jnt]
        d.qpos[adr : adr + 3] = pos
        d.qpos[adr + 3 : adr + 7] = np.asarray(quat_wxyz, dtype=np.float64) / np.linalg.norm(quat_wxyz)
        d.qvel[dof : dof + 6] = 0.0
        mujoco.mj_forward(m, d)

    def set_entity_pose(self, name: str, pos, quat_wxyz) -> None:
        """Move a token (by name) to a world pose by moving the free body that carries it."""
        if name not in self._entity_body:
            raise ValueError(f"{name!r} is not a MuJoCo entity of {self.task}")
        row = 1 + [e.name for e in self.spec_task.entities].index(name)
        bid = self._entity_body[name]
        poses = self._observe()["poses"].astype(np.float64)
        d = self._data
        # token = body * offset  =>  body' = token' * offset^-1
        r_body = d.xmat[bid].reshape(3, 3)
        r_tok = rot.quat_to_matrix(poses[row, 3:])
        off_r = r_body.T @ r_tok
        off_p = r_body.T @ (poses[row, :3] - d.xpos[bid])
        r_new = rot.quat_to_matrix(np.asarray(quat_wxyz, dtype=np.float64)) @ off_r.T
        self.set_body_pose(int(bid), np.asarray(pos) - r_new @ off_p, rot.matrix_to_quat(r_new))

    # ------------------------------------------------------------------ scene transform
    def _restore_fixtures(self) -> None:
        for bid, _, pos, quat in self._fixtures:
            self._model.body_pos[bid] = pos
            self._model.body_quat[bid] = quat

    def _sample_transform_on_table(self, tries: int = 100) -> tuple[float, float, float]:
        """Draw ``(yaw, tx, ty)`` that keeps every entity token over the table (2 cm margin).

        A transform with ranges is redrawn (up to ``tries`` times) when it would move an entity
        off the table, so the layout is conditioned on staying on it; a constant transform
        that does raises ``ValueError`` naming the entity.
        """
        half = np.asarray(getattr(self._env, "table_full_size", (0.8, 0.8)), dtype=np.float64)[:2] / 2 - 0.02
        centre = np.asarray(getattr(self._env, "table_offset", (0.0, 0.0)), dtype=np.float64)[:2]
        points = self._observe()["poses"][1:, :3].astype(np.float64)
        names = [e.name for e in self.spec_task.entities]
        for _ in range(tries):
            g = self.scene_transform.sample(self.np_random)
            xy = planar_transform_points(points, g[0], (g[1], g[2]), self.spec_task.pivot_xy)[:, :2]
            off = np.flatnonzero((np.abs(xy - centre) > half).any(axis=1))
            if not len(off):
                return g
        raise ValueError(
            f"scene transform {self.scene_transform} moves {[names[i] for i in off]} of {self.task} off the "
            "table; use a smaller shift or yaw range for this task/variant"
        )

    def _apply_scene_transform(self, yaw: float, tx: float, ty: float) -> None:
        m, d = self._model, self._data
        pivot, shift, qz = self.spec_task.pivot_xy, (tx, ty), yaw_quat(yaw)
        eef_pos, eef_mat = self.eef_pose()
        for adr in self._free_qpos:
            d.qpos[adr : adr + 3] = planar_transform_points(d.qpos[adr : adr + 3], yaw, shift, pivot)
            q = np.empty(4)
            mujoco.mju_mulQuat(q, qz, d.qpos[adr + 3 : adr + 7].copy())
            d.qpos[adr + 3 : adr + 7] = q
        for bid, parent, pos, quat in self._fixtures:
            parent_pos = d.xpos[parent]
            if not np.allclose(d.xquat[parent], [1, 0, 0, 0]):
                raise RuntimeError("scene transform: fixtures must have an unrotated parent body")
            m.body_pos[bid] = planar_transform_points(parent_pos + pos, yaw, shift, pivot) - parent_pos
            q = np.empty(4)
            mujoco.mju_mulQuat(q, qz, quat)
            m.body_quat[bid] = q
        mujoco.mj_forward(m, d)
        if self.scene_transform.move_robot:
            target_pos = planar_transform_points(eef_pos, yaw, shift, pivot)
            self._solve_arm_ik(target_pos, rot.yaw_matrix(yaw) @ eef_mat)

    def _solve_arm_ik(self, target_pos: np.ndarray, target_mat: np.ndarray, iters: int = 200) -> None:
        """Damped least squares on the arm joints (kinematics only) to put the EEF at a pose."""
        m, d = self._model, self._data
        jacp, jacr = np.empty((3, m.nv)), np.empty((3, m.nv))
        lo, hi = m.jnt_range[self._robot._ref_joint_indexes].T
        for _ in range(iters):
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            pos, mat = self.eef_pose()
            err = np.concatenate([target_pos - pos, rot.matrix_to_rotvec(target_mat @ mat.T)])
            if np.linalg.norm(err[:3]) < 1e-4 and np.linalg.norm(err[3:]) < 1e-3:
                break
            mujoco.mj_jacSite(m, d, jacp, jacr, self._eef_site)
            jac = np.concatenate([jacp[:, self._arm_dof], jacr[:, self._arm_dof]])
            dq = jac.T @ np.linalg.solve(jac @ jac.T + 1e-4 * np.eye(6), err)
            d.qpos[self._arm_qpos] = np.clip(d.qpos[self._arm_qpos] + dq, lo, hi)
        else:
            raise RuntimeError(f"scene transform: IK did not reach the moved EEF pose (error {err})")
        d.qvel[self._arm_dof] = 0.0
        mujoco.mj_forward(m, d)


def make_robosuite_env(spec: TaskSpec, **overrides):
    """The raw robosuite env of a task, configured as the pose-token env uses it: Panda, absolute
    world OSC_POSE, no robosuite rendering or camera observations, soft resets, no horizon.

    robosuite's generator is seeded (0) at construction because it also draws parts of the model
    when it is built (Lift's cube size, 0.040-0.044 m): unseeded, every env instance (every
    process, every eval worker) had its own, so one episode seed gave different scenes."""
    kwargs = dict(
        robots="Panda",
        controller_configs=absolute_pose_controller_config(),
        has_renderer=False,
        has_offscreen_renderer=False,
        use_camera_obs=False,
        reward_shaping=False,
        reward_scale=1.0,
        control_freq=CONTROL_FREQ,
        ignore_done=True,
        hard_reset=False,
        seed=0,
    )
    kwargs.update(spec.env_kwargs)
    kwargs.update(overrides)
    return spec.load_env_class()(**kwargs)
