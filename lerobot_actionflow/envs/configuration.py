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
    ENV_AGENT_POS,
    ENV_POSES,
    ENV_STATE,
    ENV_TO_DATASET_KEY,
    env_pixels_key,
    feature_shapes,
    image_key,
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
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        spec = get_task(str(self.task))  # KeyError naming the known tasks
        self.task = spec.name
        if self.fps != CONTROL_FREQ:
            raise ValueError(
                f"fps must be the control rate {CONTROL_FREQ} of the robosuite tasks, got {self.fps}"
            )
        for name in ("scene_move_robot", "terminate_on_success"):
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
        self.scene_transform_kwargs()  # validate early

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
            "max_episode_steps": self.episode_length,
            # LeRobot's async workers each build one env: nothing would reuse MuJoCo's asset cache.
            "asset_cache": False,
        }
