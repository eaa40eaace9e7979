"""The LeRobot feature spec of the schema and the env observation -> dataset frame mapping.

Keys, dtypes and shapes are the schema's (:mod:`lerobot_actionflow.schema`); this module only
puts them in LeRobot's ``features`` format and adds the optional camera images.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lerobot_actionflow.schema import (
    ACTION_KEY,
    ENV_PIXELS,
    ENV_TO_DATASET_KEY,
    feature_shapes,
    image_key,
)


def default_repo_id(task: str) -> str:
    """The dataset repo id used when none is given: ``local/<task in lower case>``."""
    return f"local/{task.lower()}"


def schema_features(
    num_tokens: int,
    cameras: tuple[str, ...] = (),
    image_size: tuple[int, int] = (84, 84),
    image_dtype: str = "video",
) -> dict[str, dict]:
    """The ``features`` argument of ``LeRobotDataset.create`` for ``num_tokens`` = N poses (EEF
    included): the schema's float32 features, then one ``(H, W, 3)`` image feature per camera,
    stored as ``image_dtype`` (``"video"`` or ``"image"``)."""
    if image_dtype not in ("video", "image"):
        raise ValueError(f"image_dtype must be 'video' or 'image', got {image_dtype!r}")
    feats = {
        key: {"dtype": "float32", "shape": shape, "names": None}
        for key, shape in feature_shapes(num_tokens).items()
    }
    for cam in cameras:
        feats[image_key(cam)] = {
            "dtype": image_dtype,
            "shape": (*image_size, 3),
            "names": ["height", "width", "channels"],
        }
    return feats


def frame_from_obs(obs: dict[str, Any], action: np.ndarray, task: str) -> dict[str, Any]:
    """One ``add_frame`` dict from a pose-token env observation and the action taken on it: the
    env keys renamed to dataset keys (``ENV_TO_DATASET_KEY``), the camera images of
    ``obs[ENV_PIXELS]`` as uint8, the action, and the task description."""
    frame = {key: np.asarray(obs[env_key], dtype=np.float32) for env_key, key in ENV_TO_DATASET_KEY.items()}
    frame[ACTION_KEY] = np.asarray(action, dtype=np.float32)
    frame["task"] = task
    for cam, img in obs.get(ENV_PIXELS, {}).items():
        frame[image_key(cam)] = np.asarray(img, dtype=np.uint8)
    return frame
