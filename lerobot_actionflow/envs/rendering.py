"""Offscreen camera images of a MuJoCo model, and the release of their GL contexts at exit.

:class:`CameraRenderer` draws RGB frames with ``mujoco.Renderer`` on a model and its data
(robosuite's own renderer stays off): visual geoms only (robosuite puts collision geoms in group
0 and visual geoms in group 1), no multisample anti-aliasing (it doubles the cost of a frame on
a CPU, software-EGL renderer for a barely visible difference at these sizes). Without a GPU a
frame costs tens of milliseconds, more than a physics step. One ``mujoco.Renderer`` (one GL
context) is kept per image size and made on first use; the same renderer also draws metric depth
and per-pixel geom ids (:meth:`CameraRenderer.render_depth_and_geoms`, for point clouds).

GL contexts must be freed before MuJoCo terminates its EGL display at exit. MuJoCo registers
that ``atexit`` hook when its GL module is first imported, i.e. by the first renderer; ours is
registered after it, so it runs first and closes every live renderer.
"""

from __future__ import annotations

import atexit
import weakref

import mujoco
import numpy as np

#: Our camera names -> robosuite's.
CAMERA_ALIASES = {"wrist": "robot0_eye_in_hand", "agentview": "agentview"}

_LIVE: weakref.WeakSet[CameraRenderer] = weakref.WeakSet()
_EXIT_HOOK: list = []


def _close_all_at_exit() -> None:
    for renderer in list(_LIVE):
        renderer.close()


class CameraRenderer:
    """RGB images from the cameras of ``model`` in the state ``data``.

    Args:
        model, data: the MuJoCo model and data to draw (the model's offscreen sampling is set to
            none and its offscreen buffer grown as needed).
        owner: a name for error messages (the task).
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, owner: str = ""):
        self._model, self._data, self._owner = model, data, owner
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}
        model.vis.quality.offsamples = 0
        self._scene_option = mujoco.MjvOption()
        self._scene_option.geomgroup[0] = 0  # hide the collision geoms
        # Geometry passes (depth, segmentation): no sites either, they are markers, not surfaces.
        self._geometry_option = mujoco.MjvOption()
        self._geometry_option.geomgroup[0] = 0
        self._geometry_option.sitegroup[:] = 0

    def camera_id(self, camera: str) -> int:
        """Id of a camera given by alias (``"wrist"``, ``"agentview"``) or by its model name.

        Raises:
            ValueError: no such camera in the model.
        """
        name = CAMERA_ALIASES.get(camera, camera)
        cid = mujoco.mj_name2id(self._model, mujoco.mjtObj.mjOBJ_CAMERA, name)
        if cid < 0:
            known = [self._model.camera(i).name for i in range(self._model.ncam)]
            raise ValueError(f"task {self._owner} has no camera {camera!r}; known: {known} and 'wrist'")
        return cid

    def _renderer(self, height: int, width: int) -> mujoco.Renderer:
        key = (height, width)
        renderer = self._renderers.get(key)
        if renderer is None:
            vis = self._model.vis.global_
            vis.offwidth, vis.offheight = max(vis.offwidth, width), max(vis.offheight, height)
            renderer = self._renderers[key] = mujoco.Renderer(self._model, height, width)
            _LIVE.add(self)
            if not _EXIT_HOOK:
                _EXIT_HOOK.append(atexit.register(_close_all_at_exit))
        return renderer

    def render(self, camera: str, height: int, width: int) -> np.ndarray:
        """RGB ``uint8 (height, width, 3)`` from ``camera`` (alias or model name)."""
        renderer = self._renderer(height, width)
        renderer.update_scene(self._data, camera=self.camera_id(camera), scene_option=self._scene_option)
        return renderer.render()

    def render_depth_and_geoms(self, camera: str, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
        """Metric planar depth ``float32 (height, width)`` (metres along the camera axis) and the
        geom id of each pixel ``int32 (height, width)`` (``-1``: background or no geom), from one
        render pass, row 0 at the top of the image (``mujoco.Renderer`` flips OpenGL's
        bottom-up rows and linearises its depth buffer).

        ``mujoco.Renderer`` draws its depth pass with segment colours (``mjRND_SEGMENT`` and
        ``mjRND_IDCOLOR``), so the colour buffer of that same frame holds each pixel's segment id
        ``r + 256 g + 65536 b`` (0: background, else a scene geom's ``segid + 1``): reading it
        instead of drawing a second, segmentation pass halves the cost of a point cloud's
        renders (MugHang at 128x128: 12 ms instead of 34 ms per camera on a 2-core CPU; the same
        depth and ids).
        """
        renderer = self._renderer(height, width)
        renderer.update_scene(self._data, camera=self.camera_id(camera), scene_option=self._geometry_option)
        renderer.enable_depth_rendering()
        try:
            depth = renderer.render()
        finally:
            renderer.disable_depth_rendering()
        colour = np.empty((height, width, 3), dtype=np.uint8)
        # The renderer's viewport and MjrContext (no public accessor); its GL context is current.
        mujoco.mjr_readPixels(colour, None, renderer._rect, renderer._mjr_context)
        colour = np.flipud(colour).astype(np.int64)
        segment = colour[..., 0] | (colour[..., 1] << 8) | (colour[..., 2] << 16)
        scene = renderer.scene
        geom_of_segment = np.full(scene.ngeom + 1, -1, dtype=np.int32)
        for g in scene.geoms[: scene.ngeom]:
            if g.segid != -1 and g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                geom_of_segment[g.segid + 1] = g.objid
        return depth, geom_of_segment[segment]

    def close(self) -> None:
        """Release the GL contexts (made again on the next :meth:`render`)."""
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()
