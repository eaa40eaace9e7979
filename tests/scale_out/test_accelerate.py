"""lerobot-train and actionflow-train under `accelerate launch` with 2 processes (DDP over gloo
on the CPU)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from ..synthetic_dataset import make_reach_dataset

BIN = Path(sys.executable).parent
POLICIES = {
    "actionflow": ["--policy.dim=32", "--policy.num_layers=1", "--policy.num_heads=2", "--policy.head_dim=8",
                   "--policy.horizon=8", "--policy.n_action_steps=4"],
    "euclidean_flow": ["--policy.n_layer=1", "--policy.n_emb=32", "--policy.n_head=2", "--policy.horizon=8",
                       "--policy.n_action_steps=4"],
}  # fmt: skip


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_reach_dataset(tmp_path_factory.mktemp("ddp") / "data")


TRAIN_SCRIPTS = {
    "lerobot-train": [str(BIN / "lerobot-train")],
    # the in-memory frame source in every rank (run as a module: no console script needed)
    "actionflow-train": ["-m", "lerobot_actionflow.train"],
}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("policy", "script"),
    [
        ("actionflow", "lerobot-train"),
        ("euclidean_flow", "lerobot-train"),
        ("actionflow", "actionflow-train"),
    ],
)
def test_two_process_training(policy, script, dataset, tmp_path):
    out = tmp_path / "run"
    cmd = [
        str(BIN / "accelerate"), "launch", "--multi_gpu", "--num_processes=2", "--num_machines=1",
        "--mixed_precision=no", "--dynamo_backend=no", *TRAIN_SCRIPTS[script],
        f"--policy.type={policy}", "--policy.device=cpu", "--policy.push_to_hub=false",
        "--dataset.repo_id=local/reach", f"--dataset.root={dataset}", f"--output_dir={out}",
        "--steps=3", "--save_freq=3", "--batch_size=4", "--num_workers=0", "--log_freq=1",
        "--wandb.enable=false", *POLICIES[policy],
    ]  # fmt: skip
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1", "WANDB_MODE": "disabled"}
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600, cwd=tmp_path)
    log = res.stdout + res.stderr
    assert res.returncode == 0, log[-4000:]
    assert "Effective batch size: 4 x 2 = 8" in log, "training did not run in 2 processes"
    assert ("in-memory frame source" in log) == (script == "actionflow-train")
    assert (out / "checkpoints" / "000003" / "pretrained_model" / "model.safetensors").is_file()
