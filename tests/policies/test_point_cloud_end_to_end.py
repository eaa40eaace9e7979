"""Collect -> train -> eval on MugHang with point clouds, through the real entry points, tiny:
one expert episode with 64-point clouds, two training steps of a point-token ActionFlow that
sees the hanger only in the cloud, one 10-step ``lerobot-eval`` episode with clouds from the env."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_actionflow.data.collect import main as collect
from lerobot_actionflow.schema import POINT_CLOUD_KEY

POINTS = 64


def _bin(name: str) -> str:
    return str(Path(sys.executable).with_name(name))


def _run(cmd, cwd):
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    env.setdefault("MUJOCO_GL", "egl")
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600, cwd=cwd)
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]


@pytest.mark.slow
def test_collect_train_eval_mug_hang_with_point_clouds(tmp_path):
    data = tmp_path / "data"
    cloud = ["--point-cloud", "--point-cloud-points", str(POINTS), "--point-cloud-image-size", "32"]
    assert collect(["--task", "MugHang_D0", "--episodes", "1", "--root", str(data),
                    "--repo-id", "local/mug_pc", "--no-progress", *cloud]) == 0  # fmt: skip
    run = tmp_path / "run"
    _run(
        [_bin("actionflow-train"), "--policy.type=actionflow", "--policy.device=cpu",
         "--policy.push_to_hub=false", "--dataset.repo_id=local/mug_pc", f"--dataset.root={data}",
         f"--output_dir={run}", "--steps=2", "--save_freq=2", "--batch_size=4", "--num_workers=0",
         "--wandb.enable=false", f"--policy.point_cloud_key={POINT_CLOUD_KEY}",
         "--policy.point_cloud_groups=8", "--policy.point_cloud_group_size=8", "--policy.pose_entities=[0,1]",
         "--policy.dim=32", "--policy.num_layers=1", "--policy.num_heads=2", "--policy.head_dim=8",
         "--policy.horizon=8", "--policy.n_action_steps=4"],
        tmp_path,
    )  # fmt: skip
    ckpt = run / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((ckpt / "config.json").read_text())
    assert config["point_cloud_key"] == POINT_CLOUD_KEY
    assert config["input_features"][POINT_CLOUD_KEY]["shape"] == [POINTS, 3]
    out = tmp_path / "eval"
    _run(
        [_bin("lerobot-eval"), f"--policy.path={ckpt}", "--policy.device=cpu", "--env.type=actionflow",
         "--env.task=MugHang_D0", "--env.point_cloud=true", f"--env.point_cloud_points={POINTS}",
         "--env.point_cloud_image_size=32", "--env.episode_length=10", "--env.visualization_height=32",
         "--env.visualization_width=32", "--eval.n_episodes=1", "--eval.batch_size=1",
         "--eval.use_async_envs=false", f"--output_dir={out}", "--seed=3"],
        tmp_path,
    )  # fmt: skip
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1
