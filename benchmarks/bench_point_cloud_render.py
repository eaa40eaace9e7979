"""A point-cloud observation with one render pass per camera against two (MuJoCo's own depth pass
then its segmentation pass), side by side in one process.

``CameraRenderer.render_depth_and_geoms`` reads the geom ids from the colour buffer of the depth
pass; the reference draws a separate segmentation pass with ``mujoco.Renderer``'s public API.
Both give the same depth and ids (tests/envs/test_env_point_cloud.py). Prints the median time of
``get_observation()`` (physics untouched: the cloud, its FPS and the pose rows) for each, and
their ratio::

    MUJOCO_GL=egl python benchmarks/bench_point_cloud_render.py [--task MugHang_D0] [--calls 15 --rounds 3]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import mujoco
import numpy as np

import lerobot_actionflow  # noqa: F401  (registers the envs)
from lerobot_actionflow.envs.rendering import CameraRenderer


def two_passes(self: CameraRenderer, camera: str, height: int, width: int):
    """Depth, then MuJoCo's segmentation pass: the same outputs as ``render_depth_and_geoms``."""
    renderer = self._renderer(height, width)
    renderer.update_scene(self._data, camera=self.camera_id(camera), scene_option=self._geometry_option)
    try:
        renderer.enable_depth_rendering()
        depth = renderer.render()
        renderer.enable_segmentation_rendering()
        seg = renderer.render()
    finally:
        renderer.disable_segmentation_rendering()
    return depth, np.where(seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM, seg[..., 0], -1).astype(np.int32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="MugHang_D0")
    ap.add_argument("--calls", type=int, default=15, help="observations per variant and round")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds")
    args = ap.parse_args()
    env = gym.make(f"lerobot_actionflow/{args.task}-v0", point_cloud=True)
    env.reset(seed=1)
    one_pass = CameraRenderer.render_depth_and_geoms
    times: dict[str, list[float]] = {"two passes": [], "one pass": []}
    try:
        for _ in range(args.rounds):
            for name, method in (("two passes", two_passes), ("one pass", one_pass)):
                CameraRenderer.render_depth_and_geoms = method
                for _ in range(args.calls):
                    start = time.perf_counter()
                    env.unwrapped.get_observation()
                    times[name].append(time.perf_counter() - start)
    finally:
        CameraRenderer.render_depth_and_geoms = one_pass
        env.close()
    for name, values in times.items():
        median_ms = 1000 * np.median(values)
        print(
            f"{args.task} observation with point cloud, {name}: {median_ms:.1f} ms (median of {len(values)})"
        )
    print(f"ratio two / one: {np.median(times['two passes']) / np.median(times['one pass']):.2f}")


if __name__ == "__main__":
    main()
