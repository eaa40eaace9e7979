"""LeRobot env type ``actionflow``: ``--env.type=actionflow --env.task=Lift``.

LeRobot's ``make_env`` (``lerobot/envs/factory.py``) calls :meth:`EnvConfig.create_envs`, which
imports :attr:`ActionFlowEnvConfig.package_name` if :attr:`gym_id` is not registered yet and
``gym.make``s it once per sub-env (``SyncVectorEnv``, or ``AsyncVectorEnv`` with forkserver
workers, which import this module again and so register the ids themselves).

Its ``features`` (keyed by env observation key, e.g. ``pixels/<camera>`` for an image) and
``features_map`` (env key -> dataset / policy key, as LeRobot's ``preprocess_observation``
renames them) are built from :mod:`lerobot_actionflow.schema`, which holds the keys and shapes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

import lerobot_actionflow.envs as _envs  # registers the gym ids (also in async workers)
from lerobot_actionflow.envs.tasks import CONTROL_FREQ, get_task
from lerobot_actionflow.schema import (
    ACTION_KEY,
    DEFAULT_POINT_CLOUD_POINTS,
    ENV_AGENT_POS,
    ENV_POINT_CLOUD,
    ENV_POSES,
    ENV_STATE,
    ENV_TO_DATASET_KEY,
    POINT_CLOUD_KEY,
    env_pixels_key,
    feature_shapes,
    image_key,
    point_cloud_shape,
)

#: LeRobot feature type of each non-image env observation.
_FEATURE_TYPES = {
    ENV_POSES: FeatureType.STATE,
    ENV_AGENT_POS: FeatureType.STATE,
    ENV_STATE: FeatureType.ENV,
}


@EnvConfig.register_subclass("actionflow")
@dataclass
class ActionFlowEnvConfig(EnvConfig):
    """A pose-token task (see :mod:`lerobot_actionflow.envs.pose_env`).

    Attributes:
        task: task name (``Lift``, ``Can``, ``Square``, ``ToolHang``, ``StackThree_D0``, ...).
        episode_length: steps before truncation; ``None`` for the task's own length.
        cameras: comma-separated image observations (``"wrist,agentview"``); empty for none.
        observation_height, observation_width: size of those images.
        render_camera, visualization_height, visualization_width: the ``render()`` view
            (``lerobot-eval`` videos).
        scene_yaw, scene_x, scene_y: ``(low, high)`` ranges of a planar scene transform drawn at
            each reset (radians, metres); all zero for none. See
            :mod:`lerobot_actionflow.envs.scene_transform` for the valid range.
        scene_move_robot: move the arm's initial EEF pose with the scene.
        terminate_on_success: end an episode at its first success step.
        point_cloud: add ``observation.point_cloud`` ``(point_cloud_points, 3)``, world/base
            frame, metres (:mod:`lerobot_actionflow.envs.point_cloud`).
        point_cloud_points: M, the points of the cloud.
        point_cloud_cameras: comma-separated depth cameras fused into it (two or more); empty
            for the task's own (:attr:`TaskSpec.point_cloud_cameras`).
        point_cloud_image_size: square depth image size per camera, in pixels.
        point_cloud_box_low, point_cloud_box_high: the crop box corners (world frame, metres);
            both ``None`` for the task's action workspace box.
    """

    task: str | None = "Lift"
    fps: int = CONTROL_FREQ
    episode_length: int | None = None
    cameras: str = ""
    observation_height: int = 84
    observation_width: int = 84
    render_mode: str = "rgb_array"
    render_camera: str = "agentview"
    visualization_height: int = 256
    visualization_width: int = 256
    scene_yaw: tuple[float, float] = (0.0, 0.0)
    scene_x: tuple[float, float] = (0.0, 0.0)
    scene_y: tuple[float, float] = (0.0, 0.0)
    scene_move_robot: bool = False
    terminate_on_success: bool = True
    point_cloud: bool = False
    point_cloud_points: int = DEFAULT_POINT_CLOUD_POINTS
    point_cloud_cameras: str = ""
    point_cloud_image_size: int = 128
    point_cloud_box_low: tuple[float, float, float] | None = None
    point_cloud_box_high: tuple[float, float, float] | None = None
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        spec = get_task(str(self.task))  # KeyError naming the known tasks
        self.task = spec.name
        if self.fps != CONTROL_FREQ:
            raise ValueError(
                f"fps must be the control rate {CONTROL_FREQ} of the robosuite tasks, got {self.fps}"
            )
        for name in ("scene_move_robot", "terminate_on_success", "point_cloud"):
            if not isinstance(getattr(self, name), bool):  # a string like "false" would be truthy
                raise TypeError(f"{name} must be a bool, got {getattr(self, name)!r}")
        sizes = ("observation_height", "observation_width", "visualization_height", "visualization_width")
        for name in sizes:
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1 pixel, got {getattr(self, name)}")
        if self.episode_length is None:
            self.episode_length = spec.episode_length
        shapes = feature_shapes(spec.num_tokens)
        self.features = {ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=shapes[ACTION_KEY])}
        self.features_map = {ACTION_KEY: ACTION_KEY}
        for env_key, ftype in _FEATURE_TYPES.items():
            key = ENV_TO_DATASET_KEY[env_key]
            self.features[env_key] = PolicyFeature(type=ftype, shape=shapes[key])
            self.features_map[env_key] = key
        for cam in self.camera_list:
            self.features[env_pixels_key(cam)] = PolicyFeature(
                type=FeatureType.VISUAL, shape=(self.observation_height, self.observation_width, 3)
            )
            self.features_map[env_pixels_key(cam)] = image_key(cam)
        if self.point_cloud:
            self.features[ENV_POINT_CLOUD] = PolicyFeature(
                type=FeatureType.STATE, shape=point_cloud_shape(self.point_cloud_points)
            )  # STATE: the type LeRobot gives an ``observation.*`` array of a dataset
            self.features_map[ENV_POINT_CLOUD] = POINT_CLOUD_KEY
        self.scene_transform_kwargs()  # validate early
        self.point_cloud_kwargs()

    @property
    def camera_list(self) -> list[str]:
        return [c.strip() for c in self.cameras.split(",") if c.strip()]

    @property
    def package_name(self) -> str:
        return "lerobot_actionflow.envs"

    @property
    def gym_id(self) -> str:
        return get_task(str(self.task)).gym_id

    def scene_transform_kwargs(self) -> dict | None:
        """The scene transform as gym kwargs (``None`` when all ranges are zero)."""
        ranges = {"yaw": self.scene_yaw, "x": self.scene_x, "y": self.scene_y}
        if all(tuple(v) == (0.0, 0.0) for v in ranges.values()):
            return None
        kw = {k: tuple(float(x) for x in v) for k, v in ranges.items()}
        _envs.SceneTransform(**kw, move_robot=self.scene_move_robot)  # ValueError when out of range
        return {**kw, "move_robot": self.scene_move_robot}

    def point_cloud_kwargs(self) -> dict | bool:
        """The point-cloud settings as gym kwargs (``False`` without a point cloud)."""
        if not self.point_cloud:
            return False
        kw = {
            "num_points": int(self.point_cloud_points),
            "cameras": tuple(c.strip() for c in self.point_cloud_cameras.split(",") if c.strip()) or None,
            "image_height": int(self.point_cloud_image_size),
            "image_width": int(self.point_cloud_image_size),
            "box_low": None if self.point_cloud_box_low is None else tuple(self.point_cloud_box_low),
            "box_high": None if self.point_cloud_box_high is None else tuple(self.point_cloud_box_high),
        }
        _envs.PointCloudConfig(**kw)  # ValueError naming the bad setting
        return kw

    @property
    def gym_kwargs(self) -> dict:
        return {
            "cameras": tuple(self.camera_list),
            "image_height": self.observation_height,
            "image_width": self.observation_width,
            "render_mode": self.render_mode,
            "render_camera": self.render_camera,
            "render_height": self.visualization_height,
            "render_width": self.visualization_width,
            "scene_transform": self.scene_transform_kwargs(),
            "terminate_on_success": self.terminate_on_success,
            "point_cloud": self.point_cloud_kwargs(),
            "max_episode_steps": self.episode_length,
            # LeRobot's async workers each build one env: nothing would reuse MuJoCo's asset cache.
            "asset_cache": False,
        }
