"""The dataset / env / policy contract: feature names, shapes and the action layout.

Torch-free and LeRobot-free, so that the envs, the data tools, the policies and the configs all
import their keys and shapes from here (tensor helpers on the action layout live beside it in
:mod:`lerobot_actionflow.schema.tensors`).

Dataset and policy features, and the env observation keys they come from (LeRobot's
``preprocess_observation`` maps ``agent_pos`` -> ``observation.state``, ``environment_state`` ->
``observation.environment_state``, any other array key ``k`` -> ``observation.k``):

| dataset / policy key              | env key              | dtype   | shape                   |
| --------------------------------- | -------------------- | ------- | ----------------------- |
| ``observation.poses``             | ``poses``            | float32 | ``(N, 7)`` pose7 rows   |
| ``observation.state``             | ``agent_pos``        | float32 | ``(11,)``               |
| ``observation.environment_state`` | ``environment_state``| float32 | ``(9 (N - 1),)``        |
| ``observation.images.<camera>``   | ``pixels/<camera>``  | uint8   | ``(H, W, 3)`` in the env|
| ``observation.point_cloud``       | ``point_cloud``      | float32 | ``(M, 3)`` (optional)   |
| ``action``                        | (the env's action)   | float32 | ``(10,)``               |

* ``pose7`` = ``[x, y, z, qw, qx, qy, qz]`` (scalar-first quaternion, ``qw >= 0``), in the robot
  base/world frame; row 0 of ``observation.poses`` is the end-effector, then the task's objects
  in a fixed order.
* ``pose9`` = ``[x, y, z, rot6d]``, where ``rot6d`` is the first two columns of the rotation
  matrix ``(r00, r10, r20, r01, r11, r21)``.
* ``observation.state`` = ``[eef pose9 (9), gripper finger qpos (2)]``.
* ``observation.environment_state`` = the object poses (rows 1.. of ``observation.poses``) as
  ``pose9``, concatenated.
* ``observation.point_cloud`` = ``M`` points ``[x, y, z]`` in metres, in the same robot
  base/world frame as the poses, in farthest-point-sampling order; stored in a dataset as
  float16 or float32 (:data:`POINT_CLOUD_DTYPES`), read back as float32.
* ``action`` = ``[absolute EEF target pose9 (9), gripper]``, gripper in ``[-1, 1]`` (-1 open,
  +1 closed).
"""

from __future__ import annotations

# -- dataset / policy feature keys
POSES_KEY = "observation.poses"
STATE_KEY = "observation.state"
ENV_STATE_KEY = "observation.environment_state"
IMAGES_PREFIX = "observation.images."
POINT_CLOUD_KEY = "observation.point_cloud"
ACTION_KEY = "action"

# -- env observation keys (raw Gymnasium dict), and the camera images' sub-dict
ENV_POSES = "poses"
ENV_AGENT_POS = "agent_pos"
ENV_STATE = "environment_state"
ENV_PIXELS = "pixels"
ENV_POINT_CLOUD = "point_cloud"
#: Env observation key -> dataset / policy key (images: ``pixels/<cam>`` -> ``IMAGES_PREFIX + cam``).
ENV_TO_DATASET_KEY = {ENV_POSES: POSES_KEY, ENV_AGENT_POS: STATE_KEY, ENV_STATE: ENV_STATE_KEY}

# -- layouts
POSE7_DIM = 7
POSE9_DIM = 9
ROT6D_DIM = 6
GRIPPER_QPOS_DIM = 2
STATE_DIM = POSE9_DIM + GRIPPER_QPOS_DIM
ACTION_DIM = POSE9_DIM + 1
#: Indices of the gripper finger positions in ``observation.state``.
STATE_GRIPPER_INDICES = tuple(range(POSE9_DIM, STATE_DIM))
#: Index of the gripper command in ``action``.
ACTION_GRIPPER_INDEX = POSE9_DIM
#: Coordinates of a point, and the default number of points ``M`` of a point cloud.
POINT_DIM = 3
DEFAULT_POINT_CLOUD_POINTS = 512
#: Dataset dtypes a point cloud may be stored as (float16: half the bytes, at most 0.5 mm of
#: rounding for coordinates below 2 m).
POINT_CLOUD_DTYPES = ("float16", "float32")


def image_key(camera: str) -> str:
    """``observation.images.<camera>``."""
    return IMAGES_PREFIX + camera


def env_pixels_key(camera: str) -> str:
    """The env-side (flattened) key ``pixels/<camera>`` of a camera image."""
    return f"{ENV_PIXELS}/{camera}"


def env_state_dim(num_tokens: int) -> int:
    """Width of ``observation.environment_state`` for ``num_tokens`` poses (EEF included)."""
    return POSE9_DIM * (num_tokens - 1)


def point_cloud_shape(num_points: int) -> tuple[int, int]:
    """Shape ``(M, 3)`` of ``observation.point_cloud`` with ``num_points`` = M points."""
    return (int(num_points), POINT_DIM)


def feature_shapes(num_tokens: int) -> dict[str, tuple[int, ...]]:
    """Shape of every non-image feature for a task with ``num_tokens`` poses (EEF included)."""
    return {
        POSES_KEY: (num_tokens, POSE7_DIM),
        STATE_KEY: (STATE_DIM,),
        ENV_STATE_KEY: (env_state_dim(num_tokens),),
        ACTION_KEY: (ACTION_DIM,),
    }
