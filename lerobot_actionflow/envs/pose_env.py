"""The pose-token Gymnasium env: one robosuite task, observed as entity poses, driven by
absolute end-effector pose targets.

Keys, layouts and shapes are the schema's (:mod:`lerobot_actionflow.schema`, for a task with
``N`` tokens); this module fills them. Every pose is in the world frame, the frame of
robosuite's observations.

- ``ENV_POSES``, pose7 rows: row 0 the end-effector (robosuite's grip site, the point the arm
  controller tracks), rows 1.. the task's entities in :attr:`TaskSpec.entities` order. World
  positions and rotation matrices are read from MuJoCo (``xpos``/``xmat`` of a body, site or
  geom; a ``pose_fn`` entity returns a position and a scalar-first quaternion), then all ``N``
  rotations become quaternions in one batched call, scalar-first with ``qw >= 0``. No robosuite
  scalar-last quaternion is involved.
- ``ENV_AGENT_POS``: the EEF as pose9, then the gripper's two finger joint positions.
- ``ENV_STATE``: rows 1.. as pose9, concatenated.
- ``ENV_PIXELS`` (only with ``cameras``): ``{camera: uint8 (H, W, 3)}``, cameras ``"wrist"``
  (robosuite's ``robot0_eye_in_hand``), ``"agentview"`` or any other camera of the model
  (:mod:`lerobot_actionflow.envs.rendering`; a frame costs more than a physics step without a GPU).
- ``ENV_POINT_CLOUD`` (only with ``point_cloud``): float32 ``(M, 3)``, points in metres in the
  same world frame, fused from two or more depth cameras, cropped to a workspace box, robot
  and table removed, farthest-point sampled (:mod:`lerobot_actionflow.envs.point_cloud`).

Action ``(ACTION_DIM,)``: ``[x, y, z, rot6d, gripper]``, the absolute EEF target pose9 in the
world frame, gripper in ``[-1, 1]`` (-1 open, +1 closed; values outside are clipped). The
position is clipped to the task's workspace box (:attr:`TaskSpec.workspace_low` /
``workspace_high``). A wrong shape, a NaN/inf entry or a degenerate 6D rotation raises
``ValueError``. The target goes to robosuite's OSC_POSE controller in absolute world mode
(:mod:`lerobot_actionflow.envs.controller`) as position + axis-angle.

Reward is 1.0 on a success step, else 0.0; ``info["is_success"]`` carries the task's check;
the episode terminates on success (``terminate_on_success``) and is truncated by Gymnasium's
``TimeLimit`` at the task's episode length when made through ``gym.make``.

Scene transform: at each reset, after the task has placed its objects, a drawn planar motion
moves the layout (:mod:`lerobot_actionflow.envs.scene_mover`) and, with ``move_robot``, the
arm's end-effector by inverse kinematics (:mod:`lerobot_actionflow.envs.arm_ik`).

Seeding: ``reset(seed=s)`` re-seeds, in place, the one numpy generator through which robosuite
samples robot initialisation noise and object placements, and the generator of the scene
transform; the same seed gives the same initial state, and with the same actions the same
episode, in any env instance (what robosuite draws at construction is seeded too).
"""

from __future__ import annotations

import ctypes
import math
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np

from lerobot_actionflow.envs.arm_ik import ArmIK
from lerobot_actionflow.envs.controller import absolute_pose_controller_config
from lerobot_actionflow.envs.point_cloud import PointCloudSensor
from lerobot_actionflow.envs.point_cloud_config import PointCloudConfig
from lerobot_actionflow.envs.rendering import CameraRenderer
from lerobot_actionflow.envs.scene_mover import SceneMover
from lerobot_actionflow.envs.scene_transform import SceneTransform
from lerobot_actionflow.envs.tasks import CONTROL_FREQ, TaskSpec, get_task
from lerobot_actionflow.rotations import (
    compose,
    inverse,
    matrix_to_axis_angle,
    matrix_to_quaternion,
    quaternion_to_matrix,
    rotation_6d_to_matrix,
    rp_to_pose7,
    rp_to_pose9,
)
from lerobot_actionflow.schema import (
    ACTION_DIM,
    ACTION_GRIPPER_INDEX,
    ENV_AGENT_POS,
    ENV_PIXELS,
    ENV_POINT_CLOUD,
    ENV_POSES,
    ENV_STATE,
    GRIPPER_QPOS_DIM,
    POSE7_DIM,
    POSE9_DIM,
    STATE_DIM,
    env_state_dim,
    point_cloud_shape,
)

#: MuJoCo data arrays (world position, row-major rotation matrix) of each kind of token element.
_FRAME_ARRAYS = {
    "body": ("xpos", "xmat"),
    "site": ("site_xpos", "site_xmat"),
    "geom": ("geom_xpos", "geom_xmat"),
}
#: The C library of this process (``malloc_trim`` where it is glibc).
_LIBC = ctypes.CDLL(None)
_OBJ_TYPES = {
    "body": mujoco.mjtObj.mjOBJ_BODY,
    "site": mujoco.mjtObj.mjOBJ_SITE,
    "geom": mujoco.mjtObj.mjOBJ_GEOM,
}


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
        asset_cache: keep the meshes and textures MuJoCo's compiler decoded in its process-wide
            asset cache (about 90 MB for Lift), so the next env built in this process compiles
            faster (about 0.3 s instead of 1.5 s). ``False`` empties the cache after building:
            for a process that builds one env, such as a ``lerobot-eval`` worker.
        point_cloud: ``True`` (default settings), a :class:`PointCloudConfig` or a dict of its
            fields, to add ``observation["point_cloud"]``; ``False`` for none.
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
        asset_cache: bool = True,
        point_cloud: bool | dict | PointCloudConfig = False,
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
        for name, size in (("image", self.image_size), ("render", self.render_size)):
            if min(size) < 1:
                raise ValueError(f"{name}_height and {name}_width must be >= 1 pixel, got {size}")
        self.scene_transform = SceneTransform.coerce(scene_transform)
        if self.scene_transform is not None and not self.spec_task.scene_transform:
            raise ValueError(f"task {self.task} does not support a scene transform (fixed goal in the arena)")
        self._ws_low = np.asarray(self.spec_task.workspace_low, dtype=np.float64)
        self._ws_high = np.asarray(self.spec_task.workspace_high, dtype=np.float64)

        self._env = make_robosuite_env(self.spec_task)
        release_compiler_memory(clear_asset_cache=not asset_cache)
        self._model: mujoco.MjModel = self._env.sim.model._model
        self._data: mujoco.MjData = self._env.sim.data._data
        self._setup_references()
        table_half = np.asarray(getattr(self._env, "table_full_size", (0.8, 0.8)), dtype=np.float64)[:2] / 2
        table_centre = np.asarray(getattr(self._env, "table_offset", (0.0, 0.0)), dtype=np.float64)[:2]
        self._scene = SceneMover(self._model, self._data, self.spec_task, table_centre, table_half)
        self._arm_ik = ArmIK(self._model, self._data, self._eef_site, self._env.robots[0]._ref_joint_indexes)
        self._renderer = CameraRenderer(self._model, self._data, self.task)
        for cam in (*self.cameras, self.render_camera):
            self._renderer.camera_id(cam)  # fail early on an unknown camera
        pc_config = PointCloudConfig.coerce(point_cloud)
        self._point_cloud = None
        if pc_config is not None:
            removed = (
                *(r.robot_model.root_body for r in self._env.robots),
                *self.spec_task.point_cloud_removed,
            )
            self._point_cloud = PointCloudSensor(
                self._env.sim, self._renderer, pc_config, self._ws_low, self._ws_high, removed,
                self.spec_task.point_cloud_cameras,
            )  # fmt: skip

        n = self.spec_task.num_tokens
        obs_spaces: dict[str, gym.Space] = {
            ENV_POSES: gym.spaces.Box(-np.inf, np.inf, (n, POSE7_DIM), np.float32),
            ENV_AGENT_POS: gym.spaces.Box(-np.inf, np.inf, (STATE_DIM,), np.float32),
            ENV_STATE: gym.spaces.Box(-np.inf, np.inf, (env_state_dim(n),), np.float32),
        }
        if self.cameras:
            obs_spaces[ENV_PIXELS] = gym.spaces.Dict(
                {c: gym.spaces.Box(0, 255, (*self.image_size, 3), np.uint8) for c in self.cameras}
            )
        if self._point_cloud is not None:
            shape = point_cloud_shape(self._point_cloud.num_points)
            obs_spaces[ENV_POINT_CLOUD] = gym.spaces.Box(-np.inf, np.inf, shape, np.float32)
        self.observation_space = gym.spaces.Dict(obs_spaces)
        low = np.concatenate([self._ws_low, -np.ones(ACTION_DIM - 3)]).astype(np.float32)
        high = np.concatenate([self._ws_high, np.ones(ACTION_DIM - 3)]).astype(np.float32)
        self.action_space = gym.spaces.Box(low, high, (ACTION_DIM,), np.float32)
        self._last_success = False

    def _setup_references(self) -> None:
        """Ids of the EEF site, the gripper joints and every token's MuJoCo element."""
        robot = self._env.robots[0]
        self._eef_site = int(robot.eef_site_id["right"])
        self._gripper_qpos = np.asarray(robot._ref_gripper_joint_pos_indexes["right"], dtype=np.int64)
        if self._gripper_qpos.shape != (GRIPPER_QPOS_DIM,):
            raise RuntimeError(f"expected {GRIPPER_QPOS_DIM} gripper joints, got {self._gripper_qpos.shape}")
        # The arm's joints with a range: qpos addresses and (low, high) per joint.
        arm_joints = np.asarray(robot._ref_joint_indexes, dtype=np.int64)
        limited = self._model.jnt_limited[arm_joints].astype(bool)
        self._arm_qpos = np.asarray(robot._ref_joint_pos_indexes, dtype=np.int64)[limited]
        self._arm_range = self._model.jnt_range[arm_joints[limited]].copy()
        self._subgoals = self.spec_task.resolve_subgoals()
        # Token rows grouped by the kind of MuJoCo element they read (vectorised reads).
        rows: dict[str, list[tuple[int, int]]] = {k: [] for k in _OBJ_TYPES}
        self._virtual = []
        self._entity_body: dict[str, int] = {}
        for i, ent in enumerate(self.spec_task.entities):
            if ent.kind == "pose_fn":
                self._virtual.append((i + 1, ent.resolve_pose_fn()))
                continue
            ref = getattr(ent, ent.kind)
            eid = mujoco.mj_name2id(self._model, _OBJ_TYPES[ent.kind], ref)
            if eid < 0:
                raise RuntimeError(f"task {self.task}: no {ent.kind} {ref!r} for entity {ent.name!r}")
            rows[ent.kind].append((i + 1, eid))
            carrier = {"site": self._model.site_bodyid, "geom": self._model.geom_bodyid}.get(ent.kind)
            self._entity_body[ent.name] = int(eid if carrier is None else carrier[eid])  # its body
        self._rows = {
            k: (np.array([r for r, _ in v], dtype=np.int64), np.array([e for _, e in v], dtype=np.int64))
            for k, v in rows.items()
            if v
        }

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if seed is not None:
            # robosuite's samplers and robot noise all hold a reference to env.rng: reseed it in place.
            self._env.rng.bit_generator.state = np.random.default_rng(seed).bit_generator.state
        self._scene.restore_fixtures()
        self._env.reset()
        if self.scene_transform is not None and not self.scene_transform.is_identity:
            _, p_tok = self._token_frames()
            r, p = self._scene.sample(self.scene_transform, self.np_random, p_tok[1:])
            eef_p, eef_r = self.eef_pose()
            self._scene.move(r, p)
            if self.scene_transform.move_robot:
                self._arm_ik.solve(*compose(r, p, eef_r, eef_p))
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

    def render_camera_image(self, camera: str, height: int, width: int) -> np.ndarray:
        """RGB ``uint8 (height, width, 3)`` from a camera (alias or robosuite name)."""
        return self._renderer.render(camera, height, width)

    def close_renderers(self) -> None:
        """Release the offscreen GL contexts (made again on the next render)."""
        self._renderer.close()

    def close(self) -> None:
        self.close_renderers()
        if getattr(self, "_env", None) is not None:
            self._env.close()
            self._env = None

    # ------------------------------------------------------------------ actions
    def to_robosuite_action(self, action) -> np.ndarray:
        """Validate an action and convert it to robosuite's ``[pos, axis-angle, gripper]`` ``(7,)``.

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
        # One reduction first: NaN/inf anywhere makes the sum non-finite (so can large finite entries).
        if not math.isfinite(a.sum()) and not np.isfinite(a).all():
            bad = np.flatnonzero(~np.isfinite(a)).tolist()
            raise ValueError(f"action has non-finite (NaN/inf) entries at indices {bad}: {a.tolist()}")
        out = np.empty(7)
        out[:3] = np.minimum(np.maximum(a[:3], self._ws_low), self._ws_high)
        out[3:6] = matrix_to_axis_angle(rotation_6d_to_matrix(a[3:POSE9_DIM]))
        out[6] = min(max(a[ACTION_GRIPPER_INDEX], -1.0), 1.0)
        return out

    # ------------------------------------------------------------------ observations
    def eef_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World position ``(3,)`` and rotation matrix ``(3, 3)`` of the end-effector (copies)."""
        d = self._data
        return d.site_xpos[self._eef_site].copy(), d.site_xmat[self._eef_site].reshape(3, 3).copy()

    def _token_frames(self) -> tuple[np.ndarray, np.ndarray]:
        """World rotations ``(N, 3, 3)`` and positions ``(N, 3)`` of the tokens, row 0 the EEF."""
        d = self._data
        n = self.spec_task.num_tokens
        r, p = np.empty((n, 9)), np.empty((n, 3))
        r[0], p[0] = d.site_xmat[self._eef_site], d.site_xpos[self._eef_site]
        for kind, (rows, ids) in self._rows.items():
            pos_name, mat_name = _FRAME_ARRAYS[kind]
            p[rows], r[rows] = getattr(d, pos_name)[ids], getattr(d, mat_name)[ids]
        if self._virtual:
            rows = [row for row, _ in self._virtual]
            pos_quat = [fn(self._env) for _, fn in self._virtual]
            p[rows] = [pos for pos, _ in pos_quat]
            r[rows] = quaternion_to_matrix(np.array([q for _, q in pos_quat])).reshape(-1, 9)
        return r.reshape(n, 3, 3), p

    def _observe(self) -> dict[str, Any]:
        r, p = self._token_frames()
        pose9 = rp_to_pose9(r, p)
        obs: dict[str, Any] = {
            ENV_POSES: rp_to_pose7(r, p).astype(np.float32),
            ENV_AGENT_POS: np.concatenate([pose9[0], self._data.qpos[self._gripper_qpos]]).astype(np.float32),
            ENV_STATE: pose9[1:].reshape(-1).astype(np.float32),
        }
        if self.cameras:
            obs[ENV_PIXELS] = {c: self.render_camera_image(c, *self.image_size) for c in self.cameras}
        if self._point_cloud is not None:
            obs[ENV_POINT_CLOUD] = self._point_cloud()
        return obs

    # ------------------------------------------------------------------ state access
    @property
    def robosuite_env(self):
        """The wrapped robosuite environment (for experts, data conversion and tests)."""
        return self._env

    @property
    def point_cloud_sensor(self) -> PointCloudSensor | None:
        """The point-cloud sensor (``None`` without ``point_cloud``)."""
        return self._point_cloud

    def is_success(self) -> bool:
        """The task's success check on the current simulator state."""
        return bool(self._env._check_success())

    def subgoals(self) -> dict[str, bool]:
        """The task's sub-goals in the current state (:attr:`TaskSpec.subgoals`), in task order;
        ``{}`` for a task without."""
        return {} if self._subgoals is None else {k: bool(v) for k, v in self._subgoals(self._env).items()}

    def joint_limit_margin(self) -> float:
        """The smallest distance of any arm joint to its nearest range limit now, in radians
        (``inf`` for an arm without limited joints)."""
        q = self._data.qpos[self._arm_qpos]
        margins = np.minimum(q - self._arm_range[:, 0], self._arm_range[:, 1] - q)
        return float(margins.min()) if margins.size else math.inf

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
        """Move a token (by name) to a world pose by moving the free body that carries it.

        With the body's pose ``B``, the token's ``T`` and the fixed offset ``O = B^-1 T``, the
        body goes to ``B' = T' O^-1`` for the requested token pose ``T'``."""
        if name not in self._entity_body:
            raise ValueError(f"{name!r} is not a MuJoCo entity of {self.task}")
        row = 1 + [e.name for e in self.spec_task.entities].index(name)
        bid = self._entity_body[name]
        r_tok, p_tok = self._token_frames()
        d = self._data
        off = compose(*inverse(d.xmat[bid].reshape(3, 3), d.xpos[bid]), r_tok[row], p_tok[row])
        target = (
            quaternion_to_matrix(np.asarray(quat_wxyz, dtype=np.float64)),
            np.asarray(pos, dtype=np.float64),
        )
        r_new, p_new = compose(*target, *inverse(*off))
        self.set_body_pose(int(bid), p_new, matrix_to_quaternion(r_new))


def release_compiler_memory(clear_asset_cache: bool = False) -> None:
    """Give back to the OS the heap memory that compiling a model freed, optionally after
    emptying MuJoCo's asset cache.

    MuJoCo's compiler works in threads, and glibc gives each thread its own malloc arena; the
    memory they free stays mapped (about 100 MB after compiling Lift) until ``malloc_trim``
    returns the free pages. Not glibc (no ``malloc_trim``): only the cache is emptied."""
    if clear_asset_cache:
        mujoco.mj_clearCache(mujoco.mj_getCache())
    trim = getattr(_LIBC, "malloc_trim", None)
    if trim is not None:
        trim(0)


def make_robosuite_env(spec: TaskSpec, **overrides):
    """The raw robosuite env of a task, configured as the pose-token env uses it: Panda, absolute
    world OSC_POSE, no robosuite rendering or camera observations, soft resets, no horizon.

    robosuite's generator is seeded (0) at construction because it also draws parts of the model
    when it is built (Lift's cube size, 0.040-0.044 m); otherwise every env instance (every
    process, every eval worker) would draw its own, and one episode seed would give different
    scenes."""
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
