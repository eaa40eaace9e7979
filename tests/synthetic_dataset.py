"""Tiny LeRobotDatasets in the project's schema, written by the tests themselves."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from lerobot_actionflow import geometry as g
from lerobot_actionflow.data.features import schema_features
from lerobot_actionflow.geometry.se3 import compose, rp_to_pose7, rp_to_pose9
from lerobot_actionflow.schema import ACTION_KEY, ENV_STATE_KEY, POSES_KEY, STATE_KEY, image_key
from lerobot_actionflow.schema.tensors import pose_to_action


def make_reach_dataset(
    root: Path, repo_id: str = "local/reach", episodes: int = 3, length: int = 24, seed: int = 0
) -> Path:
    """Episodes in which the EEF moves in a straight line to a grasp pose above one object."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    gen = torch.Generator().manual_seed(seed)
    ds = LeRobotDataset.create(
        repo_id=repo_id, fps=20, features=schema_features(num_tokens=2), root=root, use_videos=False
    )
    for _ in range(episodes):
        r_o = g.exp(torch.tensor([0.0, 0.0, 1.0]) * (torch.rand(1, generator=gen) * 6.28 - 3.14))
        p_o = torch.tensor([0.0, 0.0, 0.82]) + 0.1 * torch.randn(3, generator=gen) * torch.tensor(
            [1.0, 1.0, 0.0]
        )
        r_goal, p_goal = compose(
            r_o, p_o, g.exp(torch.tensor([3.14159, 0.0, 0.0])), torch.tensor([0.0, 0.0, 0.03])
        )
        r_cur, p_cur = g.exp(torch.tensor([3.14159, 0.0, 0.0])), torch.tensor([-0.1, 0.0, 1.0])
        r_start, p_start = r_cur, p_cur
        for k in range(length):
            s = min(1.0, (k + 1) / (length // 2))
            r_next, p_next = g.interpolate(r_start, r_goal, s), (1 - s) * p_start + s * p_goal
            frame = {
                POSES_KEY: rp_to_pose7(torch.stack((r_cur, r_o)), torch.stack((p_cur, p_o))),
                STATE_KEY: torch.cat((rp_to_pose9(r_cur, p_cur), torch.tensor([0.04, -0.04]))),
                ENV_STATE_KEY: rp_to_pose9(r_o, p_o),
                ACTION_KEY: pose_to_action(r_next, p_next, torch.tensor(1.0 if s >= 1.0 else -1.0)),
            }
            ds.add_frame({**{k2: v.numpy().astype(np.float32) for k2, v in frame.items()}, "task": "reach"})
            r_cur, p_cur = r_next, p_next
        ds.save_episode()
    ds.finalize()
    return root


def make_camera_dataset(
    root: Path,
    image_dtype: str,
    repo_id: str = "local/cameras",
    lengths: tuple[int, ...] = (9, 14, 11),
    size: int = 32,
    seed: int = 0,
) -> Path:
    """Episodes of random poses and one random 'wrist' camera (``image_dtype`` ``"video"`` or
    ``"image"``), two tasks alternating, for comparing readers of camera features."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    rng = np.random.default_rng(seed)
    features = schema_features(
        num_tokens=2, cameras=("wrist",), image_size=(size, size), image_dtype=image_dtype
    )
    ds = LeRobotDataset.create(
        repo_id=repo_id, fps=20, features=features, root=root, use_videos=image_dtype == "video"
    )
    for e, length in enumerate(lengths):
        for _ in range(length):
            frame = {
                key: rng.standard_normal(ft["shape"]).astype(np.float32)
                for key, ft in features.items()
                if ft["dtype"] == "float32"
            }
            frame[image_key("wrist")] = rng.integers(0, 256, (size, size, 3), dtype=np.uint8)
            ds.add_frame({**frame, "task": f"task {e % 2}"})
        ds.save_episode()
    ds.finalize()
    return root
