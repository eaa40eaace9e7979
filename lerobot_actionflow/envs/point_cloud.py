"""Point-cloud observations: depth from several simulated cameras, fused in the world frame,
cropped to a workspace box, robot and table removed, farthest-point sampled to ``M`` points.

Frame and units: metres in the MuJoCo world frame of the robosuite scene, the frame of every
pose token (:mod:`lerobot_actionflow.envs.pose_env`) and of the actions, which this project
calls the robot base frame. (The Panda's base link stands at a fixed place in it, at
``(-0.56, 0, 0.912)`` unrotated in the tabletop tasks; a real robot uses its base frame for
both poses and points.)

Pipeline, per camera ``c`` (an image of ``H x W`` pixels):

1. Depth and segmentation from one render pass (:meth:`CameraRenderer.render_depth_and_geoms`):
   ``mujoco.Renderer`` returns metric planar depth ``z`` (its reverse-Z buffer already
   linearised with the model's ``znear``/``zfar``, so robosuite's ``get_real_depth_map``, which
   linearises a normalised ``[0, 1]`` buffer, must not be applied again) and the geom id of each
   pixel, both flipped to image convention (row 0 at the top).
2. Back-projection with robosuite's camera utilities: ``K`` from
   ``get_camera_intrinsic_matrix`` (``f = H / (2 tan(fovy / 2))``, principal point
   ``(W / 2, H / 2)``) and the camera-to-world pose ``T_wc`` from
   ``get_camera_extrinsic_matrix`` (OpenCV axes: x right, y down, z forward). Pixel
   ``(row v, column u)`` covers ``[u, u + 1] x [v, v + 1]``, so its centre back-projects to
   ``p_c = z K^-1 [u + 1/2, v + 1/2, 1]^T`` and ``p_w = R_wc p_c + t_wc``.
3. Removal by segmentation, exact to the pixel: a pixel is kept only if it shows a geom whose
   body is neither the world body (floor, walls), nor in the subtree of a body the task removes
   (:attr:`TaskSpec.point_cloud_removed`: the ``table``, or Can's bins and cell markers), nor
   in a robot's subtree (arm, mount, gripper), nor a mocap marker. Sites and collision geoms
   are not drawn, so they neither appear nor occlude.
4. Crop to the workspace box ``low <= p_w <= high`` (world frame; the task's action workspace
   box unless :class:`~lerobot_actionflow.envs.point_cloud_config.PointCloudConfig` gives one).

The kept points of all cameras are concatenated and reduced by :func:`farthest_point_sample`
to ``M`` points, float32 ``(M, 3)``, in sampling order (so the first ``k`` rows are themselves a
``k``-point farthest-point sample).
"""

from __future__ import annotations

import mujoco
import numpy as np

from lerobot_actionflow.envs.point_cloud_config import PointCloudConfig
from lerobot_actionflow.envs.rendering import CAMERA_ALIASES, CameraRenderer
from lerobot_actionflow.schema import POINT_DIM


def farthest_point_sample(points: np.ndarray, num_points: int, seed: int = 0) -> np.ndarray:
    """Indices ``(num_points,)`` of a farthest-point sample of ``points`` ``(K, 3)``.

    The first index is drawn uniformly with ``numpy.random.default_rng(seed)``; then, greedily,
    ``i_{k+1} = argmax_j min_{l <= k} |p_j - p_{i_l}|`` (ties: the lowest index), with the
    running minimum squared distances kept in one vector (``O(K M)`` time, ``O(K)`` memory;
    coordinates are held as three contiguous rows and every step writes into preallocated
    buffers, a few times cheaper than forming a ``(K, 3)`` difference per step). The same
    points and seed give the same indices.

    With fewer than ``num_points`` points (``K < M``), all ``K`` are ordered this way and the
    order is repeated cyclically to length ``M`` (every point appears ``floor(M / K)`` or
    ``ceil(M / K)`` times), so the output shape stays fixed.

    Raises:
        ValueError: ``points`` is not ``(K, 3)`` with ``K >= 1``, or ``num_points < 1``.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != POINT_DIM or len(pts) == 0:
        raise ValueError(f"farthest_point_sample needs points of shape (K >= 1, 3), got {pts.shape}")
    if num_points < 1:
        raise ValueError(f"num_points must be >= 1, got {num_points}")
    k = len(pts)
    m = min(num_points, k)
    coords = np.ascontiguousarray(pts.T)  # (3, K)
    chosen = np.empty(m, dtype=np.int64)
    chosen[0] = np.random.default_rng(seed).integers(k)
    dist = np.full(k, np.inf)
    sq, tmp = np.empty(k), np.empty(k)
    for i in range(1, m):
        last = coords[:, chosen[i - 1]]
        np.subtract(coords[0], last[0], out=sq)
        np.multiply(sq, sq, out=sq)
        for axis in (1, 2):
            np.subtract(coords[axis], last[axis], out=tmp)
            np.multiply(tmp, tmp, out=tmp)
            sq += tmp
        np.minimum(dist, sq, out=dist)
        chosen[i] = int(np.argmax(dist))
    if m < num_points:
        chosen = np.resize(chosen, num_points)  # cyclic repetition
    return chosen


def removed_bodies(model: mujoco.MjModel, bodies: list[int]) -> np.ndarray:
    """Boolean mask ``(nbody,)`` of the bodies whose geoms never enter the cloud: the world
    body, the subtrees of ``bodies`` (robots' root bodies, support surfaces), and mocap bodies
    (robosuite's target markers). A MuJoCo body's parent has a lower id, so one pass in id
    order marks whole subtrees."""
    mask = np.zeros(model.nbody, dtype=bool)
    mask[list(bodies)] = True
    parent = np.asarray(model.body_parentid)
    for b in range(1, model.nbody):
        mask[b] |= mask[parent[b]]
    mask |= np.asarray(model.body_mocapid) >= 0
    mask[0] = True
    return mask


class PointCloudSensor:
    """The fused, cropped, sampled point cloud of a robosuite scene (see the module docstring).

    Args:
        sim: robosuite's ``MjSim`` of the scene (for its camera utilities).
        renderer: the env's :class:`CameraRenderer` on the same model and data.
        config: a :class:`PointCloudConfig`.
        box_low, box_high: the crop box used when the config gives none.
        removed: names of the bodies whose subtrees are removed (the robots' root bodies and
            the task's :attr:`TaskSpec.point_cloud_removed`).
        cameras: the cameras used when the config gives none.

    Raises:
        ValueError: an unknown camera or body (naming the known cameras, or the body).
    """

    def __init__(self, sim, renderer: CameraRenderer, config: PointCloudConfig, box_low, box_high,
                 removed: tuple[str, ...], cameras: tuple[str, ...] = ("agentview", "sideview")):  # fmt: skip
        from robosuite.utils import camera_utils

        self._utils = camera_utils
        self._sim, self._renderer, self.config = sim, renderer, config
        model = sim.model._model
        low = config.box_low if config.box_low is not None else box_low
        high = config.box_high if config.box_high is not None else box_high
        self.box_low, self.box_high = np.asarray(low, np.float64), np.asarray(high, np.float64)
        self.cameras = tuple(config.cameras or cameras)
        self.names = [CAMERA_ALIASES.get(c, c) for c in self.cameras]
        for cam in self.cameras:
            renderer.camera_id(cam)  # ValueError naming the known cameras
        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name) for name in removed]
        if min(ids, default=0) < 0:
            raise ValueError(f"point cloud: no body {removed[ids.index(-1)]!r} to remove in the model")
        keep_body = ~removed_bodies(model, ids)
        self._keep_geom = keep_body[np.asarray(model.geom_bodyid)]  # (ngeom,)
        h, w = config.image_height, config.image_width
        v, u = np.mgrid[0:h, 0:w]
        pix = np.stack([u + 0.5, v + 0.5, np.ones_like(u, dtype=np.float64)], axis=-1).reshape(-1, 3)
        # Per-camera rays K^-1 [u + 1/2, v + 1/2, 1] (intrinsics are fixed; poses are read per call).
        self._rays = [
            pix @ np.linalg.inv(camera_utils.get_camera_intrinsic_matrix(sim, name, h, w)).T
            for name in self.names
        ]

    @property
    def num_points(self) -> int:
        return int(self.config.num_points)

    def camera_points(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """World points ``(K, 3)`` of every pixel of camera ``index`` that shows a geom, and
        those geoms' ids ``(K,)`` (nothing removed or cropped)."""
        cfg = self.config
        size = (cfg.image_height, cfg.image_width)
        depth, geoms = self._renderer.render_depth_and_geoms(self.cameras[index], *size)
        geoms = geoms.reshape(-1)
        hit = geoms >= 0
        pose = self._utils.get_camera_extrinsic_matrix(self._sim, self.names[index])
        p_cam = self._rays[index][hit] * depth.reshape(-1)[hit, None].astype(np.float64)
        return p_cam @ pose[:3, :3].T + pose[:3, 3], geoms[hit]

    def fused_points(self) -> np.ndarray:
        """World points ``(K, 3)`` of all cameras, robot and table removed, cropped to the box."""
        parts = []
        for i in range(len(self.names)):
            pts, geoms = self.camera_points(i)
            keep = self._keep_geom[geoms]
            keep &= ((pts >= self.box_low) & (pts <= self.box_high)).all(axis=1)
            parts.append(pts[keep])
        return np.concatenate(parts, axis=0)

    def __call__(self) -> np.ndarray:
        """The observation: float32 ``(M, 3)``, world frame, metres, in farthest-point order.

        When no point survives (every object outside the box or hidden), all ``M`` rows are the
        centre of the crop box, a constant that carries no scene information."""
        pts = self.fused_points()
        if len(pts) == 0:
            centre = (self.box_low + self.box_high) / 2
            return np.broadcast_to(centre, (self.num_points, POINT_DIM)).astype(np.float32)
        idx = farthest_point_sample(pts, self.num_points, self.config.seed)
        return pts[idx].astype(np.float32)
