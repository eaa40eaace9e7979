"""LeRobot's own ``diffusion`` policy trains on a dataset collected by ``actionflow-collect``."""

from __future__ import annotations

import subprocess

import pytest

from tests.data.conftest import BIN, REPO_ID, cli_env


@pytest.mark.slow
def test_lerobot_train_diffusion_on_collected_dataset(lift_dataset, tmp_path):
    out = tmp_path / "train"
    cmd = [
        str(BIN / "lerobot-train"),
        f"--dataset.repo_id={REPO_ID}",
        f"--dataset.root={lift_dataset}",
        "--policy.type=diffusion",
        # Small UNet: horizon divisible by 2 ** len(down_dims); drop = horizon - n_action - n_obs + 1.
        "--policy.horizon=8",
        "--policy.n_action_steps=4",
        "--policy.drop_n_last_frames=3",
        "--policy.down_dims=[32,64]",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--wandb.enable=false",
        f"--output_dir={out}",
        "--steps=2",
        "--batch_size=2",
        "--num_workers=0",
        "--save_checkpoint=true",
        "--save_freq=2",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=cli_env())
    assert proc.returncode == 0, proc.stderr[-4000:]
    ckpt = out / "checkpoints" / "000002" / "pretrained_model"
    assert (ckpt / "model.safetensors").exists(), sorted(p.name for p in out.rglob("*"))[:50]
