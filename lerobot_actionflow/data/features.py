"""The LeRobot feature spec of the schema and the env observation -> dataset frame mapping.

Keys, dtypes and shapes are the schema's (:mod:`lerobot_actionflow.schema`); this module only
puts them in LeRobot's ``features`` format and adds the optional camera images and point cloud.

A point cloud ``(M, 3)`` is a fixed-shape array feature: LeRobot stores it in the episode
parquet files as an Arrow fixed-size 2D array (``datasets.Array2D``) of the feature's dtype,
compressed with the rest of the row, and returns it as a float32 tensor. ``float16`` halves the
bytes of ``float32`` and rounds a coordinate below 2 m by at most 0.5 mm (2^-11 m).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lerobot_actionflow.schema import (
    ACTION_KEY,
    ENV_PIXELS,
    ENV_POINT_CLOUD,
    ENV_TO_DATASET_KEY,
    POINT_CLOUD_DTYPES,
    POINT_CLOUD_KEY,
    feature_shapes,
    image_key,
    point_cloud_shape,
)


def default_repo_id(task: str) -> str:
    """The dataset repo id used when none is given: ``local/<task in lower case>``."""
    return f"local/{task.lower()}"


def schema_features(
    num_tokens: int,
    cameras: tuple[str, ...] = (),
    image_size: tuple[int, int] = (84, 84),
    image_dtype: str = "video",
    point_cloud_points: int | None = None,
    point_cloud_dtype: str = "float16",
) -> dict[str, dict]:
    """The ``features`` argument of ``LeRobotDataset.create`` for ``num_tokens`` = N poses (EEF
    included): the schema's float32 features, then one ``(H, W, 3)`` image feature per camera,
    stored as ``image_dtype`` (``"video"`` or ``"image"``), then, with ``point_cloud_points`` =
    M, the ``(M, 3)`` point cloud stored as ``point_cloud_dtype`` (``"float16"`` or
    ``"float32"``)."""
    if image_dtype not in ("video", "image"):
        raise ValueError(f"image_dtype must be 'video' or 'image', got {image_dtype!r}")
    if point_cloud_dtype not in POINT_CLOUD_DTYPES:
        raise ValueError(f"point_cloud_dtype must be one of {POINT_CLOUD_DTYPES}, got {point_cloud_dtype!r}")
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
    if point_cloud_points is not None:
        feats[POINT_CLOUD_KEY] = {
            "dtype": point_cloud_dtype,
            "shape": point_cloud_shape(point_cloud_points),
            "names": ["points", "xyz"],
        }
    return feats


def frame_from_obs(
    obs: dict[str, Any], action: np.ndarray, task: str, point_cloud_dtype: str = "float16"
) -> dict[str, Any]:
    """One ``add_frame`` dict from a pose-token env observation and the action taken on it: the
    env keys renamed to dataset keys (``ENV_TO_DATASET_KEY``), the camera images of
    ``obs[ENV_PIXELS]`` as uint8, the point cloud (if the env gives one) as
    ``point_cloud_dtype``, the action, and the task description."""
    frame = {key: np.asarray(obs[env_key], dtype=np.float32) for env_key, key in ENV_TO_DATASET_KEY.items()}
    frame[ACTION_KEY] = np.asarray(action, dtype=np.float32)
    frame["task"] = task
    for cam, img in obs.get(ENV_PIXELS, {}).items():
        frame[image_key(cam)] = np.asarray(img, dtype=np.uint8)
    if ENV_POINT_CLOUD in obs:
        frame[POINT_CLOUD_KEY] = np.asarray(obs[ENV_POINT_CLOUD]).astype(point_cloud_dtype)
    return frame
