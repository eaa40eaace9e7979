"""``actionflow-collect --point-cloud``: the feature is written with its shape and dtype, reads
back as float32 in the base frame (through LeRobotDataset and the in-memory source alike), and a
resumed run must ask for the same point-cloud settings."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lerobot_actionflow.data.collect import main
from lerobot_actionflow.schema import POINT_CLOUD_KEY, POSES_KEY
from tests.data.conftest import REPO_ID

POINTS = 32
#: Half a millimetre: float16 rounds coordinates below 2 m by at most 2^-11 m.
FLOAT16_TOL = 2.0**-11


def _args(root, *extra):
    base = ["--task", "Lift", "--episodes", "1", "--root", str(root), "--repo-id", REPO_ID, "--no-progress"]
    cloud = ["--point-cloud", "--point-cloud-points", str(POINTS), "--point-cloud-image-size", "64"]
    return [*base, *cloud, *extra]


@pytest.fixture(scope="module")
def lift_point_cloud(tmp_path_factory):
    root = tmp_path_factory.mktemp("collect_pc") / "lift"
    assert main(_args(root)) == 0
    return root


def test_point_cloud_feature_is_stored_as_float16_and_read_as_float32(lift_point_cloud):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_actionflow.data.in_memory import InMemoryLeRobotDataset

    info = json.loads((lift_point_cloud / "meta" / "info.json").read_text())
    assert info["features"][POINT_CLOUD_KEY]["dtype"] == "float16"
    assert tuple(info["features"][POINT_CLOUD_KEY]["shape"]) == (POINTS, 3)
    meta = json.loads((lift_point_cloud / "meta" / "actionflow_collect.json").read_text())
    assert meta["point_cloud"] == {"num_points": POINTS, "cameras": ["agentview", "sideview"],
                                   "image_size": 64, "dtype": "float16"}  # fmt: skip
    ds = LeRobotDataset(REPO_ID, root=lift_point_cloud)
    first = ds[0]
    cloud = first[POINT_CLOUD_KEY]
    assert cloud.dtype == torch.float32 and tuple(cloud.shape) == (POINTS, 3)
    # Base frame, metres: at the first frame the cloud is the cube, around its pose token.
    cube = first[POSES_KEY][1, :3]
    assert (cloud - cube).norm(dim=-1).max() < 0.05
    # The in-memory source (actionflow-train) gives the same tensors.
    fast = InMemoryLeRobotDataset(ds)
    for i in (0, len(ds) - 1):
        torch.testing.assert_close(fast[i][POINT_CLOUD_KEY], ds[i][POINT_CLOUD_KEY], rtol=0, atol=0)


def test_float16_rounding_is_within_half_a_millimetre():
    x = np.random.default_rng(0).uniform(-1.99, 1.99, size=(10_000, 3)).astype(np.float32)
    err = np.abs(x.astype(np.float16).astype(np.float32) - x)
    assert err.max() <= FLOAT16_TOL


def test_resume_with_other_point_cloud_settings_is_refused(lift_point_cloud, capsys):
    assert main([a for a in _args(lift_point_cloud) if a != "--point-cloud"]) == 2  # no cloud
    assert "point_cloud" in capsys.readouterr().err
    assert main(_args(lift_point_cloud, "--point-cloud-dtype", "float32")) == 2
    assert "point_cloud" in capsys.readouterr().err
