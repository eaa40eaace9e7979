"""``lerobot-train --policy.type=euclidean_flow`` end to end: train, checkpoint, resume, reload."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

LEROBOT_TRAIN = str(Path(sys.executable).with_name("lerobot-train"))
TINY = [
    "--policy.n_layer=1",
    "--policy.n_emb=32",
    "--policy.horizon=8",
    "--policy.n_action_steps=4",
    "--policy.drop_n_last_frames=3",
    "--policy.scheduler_warmup_steps=0",
]


def _train(args: list[str]) -> str:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    out = subprocess.run([LEROBOT_TRAIN, *args], capture_output=True, text=True, timeout=300, env=env)
    log = out.stdout + out.stderr
    assert out.returncode == 0, log[-4000:]
    return log


@pytest.mark.slow
def test_train_checkpoint_resume_and_reload(tiny_dataset, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy

    out = tmp_path / "train"
    _train(
        [
            "--dataset.repo_id=local/euclidean_flow_tiny",
            f"--dataset.root={tiny_dataset}",
            "--policy.type=euclidean_flow",
            "--policy.device=cpu",
            "--policy.push_to_hub=false",
            "--wandb.enable=false",
            f"--output_dir={out}",
            "--steps=4",
            "--save_freq=2",
            "--batch_size=4",
            "--num_workers=0",
            "--log_freq=1",
            *TINY,
        ]
    )
    ckpts = out / "checkpoints"
    assert {"000002", "000004", "last"} <= {p.name for p in ckpts.iterdir()}
    weights_4 = (ckpts / "000004" / "pretrained_model" / "model.safetensors").read_bytes()

    # Resume from the last checkpoint for two more steps: the step counter continues at 5.
    log = _train(
        [
            f"--config_path={ckpts / 'last' / 'pretrained_model' / 'train_config.json'}",
            "--resume=true",
            "--steps=6",
        ]
    )
    assert "step:5 " in log and "step:1 " not in log, log[-3000:]
    last = ckpts / "last" / "pretrained_model"
    assert last.resolve().parent.name == "000006"
    assert json.loads((ckpts / "000006" / "training_state" / "training_step.json").read_text())["step"] == 6
    assert (last / "model.safetensors").read_bytes() != weights_4, "resumed training did not update weights"

    # Reload: same config and weights, identical actions for the same seed; processors reload too.
    policy = EuclideanFlowPolicy.from_pretrained(last)
    assert policy.config.n_layer == 1 and policy.config.horizon == 8
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(last))
    frames = LeRobotDataset(
        "local/euclidean_flow_tiny", root=tiny_dataset, delta_timestamps={"observation.state": [-0.1, 0.0]}
    )
    sample = frames[10]
    obs = {k: v for k, v in sample.items() if k.startswith("observation.") and k != "observation.poses"}
    obs = {k: v[-1] if v.ndim == 2 else v for k, v in obs.items()}  # current step only

    def act(p):
        p.reset()
        torch.manual_seed(123)
        return post(p.select_action(pre(dict(obs))))

    a1 = act(policy)
    policy.save_pretrained(tmp_path / "again")
    a2 = act(EuclideanFlowPolicy.from_pretrained(tmp_path / "again"))
    a3 = act(EuclideanFlowPolicy.from_pretrained(last))
    assert a1.shape == (1, 10) and torch.isfinite(a1).all()
    assert torch.equal(a1, a2) and torch.equal(a1, a3)
    # un-normalised: within the dataset's action range (min-max, clipped in normalised space)
    stats = LeRobotDataset("local/euclidean_flow_tiny", root=tiny_dataset).meta.stats["action"]
    lo, hi = torch.as_tensor(stats["min"]), torch.as_tensor(stats["max"])
    assert ((a1[0] >= lo - 1e-5) & (a1[0] <= hi + 1e-5)).all()
