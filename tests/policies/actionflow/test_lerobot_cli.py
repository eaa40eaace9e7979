"""ActionFlow through LeRobot's own CLI: train, checkpoint, resume, reload, pull from a Hub cache."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from ...synthetic_dataset import make_reach_dataset

LEROBOT_TRAIN = str(Path(sys.executable).with_name("lerobot-train"))
SMALL = [
    "--policy.dim=32", "--policy.num_layers=2", "--policy.num_heads=2", "--policy.head_dim=8",
    "--policy.num_query_points=2", "--policy.num_value_points=2", "--policy.horizon=8",
    "--policy.n_action_steps=4", "--policy.scheduler_warmup_steps=2",
]  # fmt: skip


def _env():
    return {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}


def _train(args, cwd):
    out = subprocess.run(
        [LEROBOT_TRAIN, *args], capture_output=True, text=True, cwd=cwd, env=_env(), timeout=600
    )
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-4000:]
    return out.stdout + out.stderr


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("actionflow_cli")
    root = make_reach_dataset(tmp / "data")
    out_dir = tmp / "run"
    log = _train(
        [
            "--policy.type=actionflow", "--policy.device=cpu", "--policy.push_to_hub=false",
            "--dataset.repo_id=local/reach", f"--dataset.root={root}", f"--output_dir={out_dir}",
            "--steps=4", "--save_freq=2", "--batch_size=4", "--num_workers=0", "--log_freq=1",
            "--wandb.enable=false", "--seed=7", *SMALL,
        ],
        tmp,
    )  # fmt: skip
    return tmp, root, out_dir, log


def _batch_from_dataset(root, cfg):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    delta = {"observation.poses": [i / 20 for i in cfg.observation_delta_indices]}
    delta["observation.state"] = delta["observation.poses"]
    ds = LeRobotDataset("local/reach", root=root, delta_timestamps=delta)
    item = ds[10]
    return {k: v[None] for k, v in item.items() if k.startswith("observation.")}


@pytest.mark.slow
def test_lerobot_train_checkpoints_and_resumes(trained_run):
    tmp, _, out_dir, log = trained_run
    ckpt = out_dir / "checkpoints" / "000004" / "pretrained_model"
    for name in ("config.json", "model.safetensors", "train_config.json"):
        assert (ckpt / name).is_file(), f"missing {name} in {sorted(p.name for p in ckpt.iterdir())}"
    assert list(ckpt.glob("policy_preprocessor*.json")) and list(ckpt.glob("policy_postprocessor*.json"))
    assert "loss_translation" in log or "loss" in log

    _train(
        ["--resume=true", f"--config_path={out_dir / 'checkpoints/last/pretrained_model/train_config.json'}",
         "--steps=6"],
        tmp,
    )  # fmt: skip
    assert (out_dir / "checkpoints" / "000006" / "pretrained_model" / "model.safetensors").is_file()
    state = (out_dir / "checkpoints" / "000006" / "training_state" / "training_step.json").read_text()
    assert '"step": 6' in state


@pytest.mark.slow
def test_from_pretrained_checkpoint_gives_identical_actions(trained_run, tmp_path):
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy

    _, root, out_dir, _ = trained_run
    ckpt = out_dir / "checkpoints" / "000004" / "pretrained_model"
    policy = ActionflowPolicy.from_pretrained(ckpt).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(ckpt))
    batch = pre(_batch_from_dataset(root, policy.config))

    def act(p):
        torch.manual_seed(123)
        return post(p.predict_action_chunk(batch))

    a1 = act(policy)
    policy.save_pretrained(tmp_path / "copy")
    a2 = act(ActionflowPolicy.from_pretrained(tmp_path / "copy").eval())
    assert a1.shape == (1, 8, 10)
    assert torch.equal(a1, a2)
    torch.manual_seed(124)
    assert not torch.equal(a1, post(policy.predict_action_chunk(batch))), "sampling ignores the seed"


@pytest.mark.slow
def test_pull_by_repo_id_from_offline_hub_cache(trained_run, tmp_path):
    """A checkpoint in the Hugging Face cache layout loads by repo id with HF_HUB_OFFLINE=1."""
    _, _, out_dir, _ = trained_run
    ckpt = out_dir / "checkpoints" / "000004" / "pretrained_model"
    commit = "0" * 40
    repo = tmp_path / "hub" / "models--someone--actionflow-reach"
    shutil.copytree(ckpt, repo / "snapshots" / commit)
    (repo / "refs").mkdir()
    (repo / "refs" / "main").write_text(commit)
    code = (
        "from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy\n"
        "from lerobot.policies.factory import make_pre_post_processors\n"
        "p = ActionflowPolicy.from_pretrained('someone/actionflow-reach')\n"
        "pre, post = make_pre_post_processors(p.config, pretrained_path='someone/actionflow-reach')\n"
        "print('loaded', p.config.type, sum(x.numel() for x in p.parameters()), len(pre.steps))\n"
    )
    env = {**_env(), "HF_HUB_CACHE": str(tmp_path / "hub")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "loaded actionflow" in out.stdout
