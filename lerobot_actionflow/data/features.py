"""LeRobot feature spec of the schema and the env observation -> dataset frame mapping.

| key                               | dtype   | shape          |
| --------------------------------- | ------- | -------------- |
| ``observation.poses``             | float32 | ``(N, 7)``     |
| ``observation.state``             | float32 | ``(11,)``      |
| ``observation.environment_state`` | float32 | ``(9 (N-1),)`` |
| ``observation.images.<camera>``   | video or image, ``(H, W, 3)`` uint8 | optional |
| ``action``                        | float32 | ``(10,)``      |
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lerobot_actionflow.schema import (
    ACTION_DIM,
    ACTION_KEY,
    ENV_STATE_KEY,
    IMAGES_PREFIX,
    POSES_KEY,
    STATE_DIM,
    STATE_KEY,
)


def schema_features(
    num_tokens: int,
    cameras: tuple[str, ...] = (),
    image_size: tuple[int, int] = (84, 84),
    image_dtype: str = "video",
) -> dict[str, dict]:
    """The ``features`` argument of ``LeRobotDataset.create`` for ``num_tokens`` = N poses (EEF
    included) and optional cameras stored as ``image_dtype`` (``"video"`` or ``"image"``)."""
    if image_dtype not in ("video", "image"):
        raise ValueError(f"image_dtype must be 'video' or 'image', got {image_dtype!r}")
    feats = {
        POSES_KEY: {"dtype": "float32", "shape": (num_tokens, 7), "names": None},
        STATE_KEY: {"dtype": "float32", "shape": (STATE_DIM,), "names": None},
        ENV_STATE_KEY: {"dtype": "float32", "shape": (9 * (num_tokens - 1),), "names": None},
        ACTION_KEY: {"dtype": "float32", "shape": (ACTION_DIM,), "names": None},
    }
    for cam in cameras:
        feats[IMAGES_PREFIX + cam] = {
            "dtype": image_dtype,
            "shape": (*image_size, 3),
            "names": ["height", "width", "channels"],
        }
    return feats


def frame_from_obs(obs: dict[str, Any], action: np.ndarray, task: str) -> dict[str, Any]:
    """One ``add_frame`` dict from a pose-token env observation and the action taken on it."""
    frame = {
        POSES_KEY: np.asarray(obs["poses"], dtype=np.float32),
        STATE_KEY: np.asarray(obs["agent_pos"], dtype=np.float32),
        ENV_STATE_KEY: np.asarray(obs["environment_state"], dtype=np.float32),
        ACTION_KEY: np.asarray(action, dtype=np.float32),
        "task": task,
    }
    for cam, img in obs.get("pixels", {}).items():
        frame[IMAGES_PREFIX + cam] = np.asarray(img, dtype=np.uint8)
    return frame
