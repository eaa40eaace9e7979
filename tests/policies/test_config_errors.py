"""Configs that cannot work are refused, and LeRobot's CLI shows the config's own message."""

import os
import subprocess
import sys
from pathlib import Path

import draccus
import pytest
from draccus.utils import DecodingError
from lerobot.configs.train import TrainPipelineConfig

from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig
from lerobot_actionflow.policies.config_errors import PolicyConfigError
from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig

LEROBOT_TRAIN = str(Path(sys.executable).with_name("lerobot-train"))

# (config class, overrides, what the message must say)
UNUSABLE = [
    (ActionflowConfig, {"dim": 33}, r"`dim` must be even"),
    (ActionflowConfig, {"num_value_points": -1}, r"`num_value_points` must be an integer >= 1"),
    (ActionflowConfig, {"noise_kappa": 0.0}, r"`noise_kappa` must be > 0"),
    (ActionflowConfig, {"dropout": 1.0}, r"`dropout` must be in \[0, 1\)"),
    (ActionflowConfig, {"adaptation_frame": "base"}, r"`adaptation_frame` must be one of"),
    (EuclideanFlowConfig, {"n_emb": 30, "n_head": 4}, r"`n_emb` \(30\) must be divisible by `n_head` \(4\)"),
    (EuclideanFlowConfig, {"backbone": "unet", "down_dims": ()}, r"`down_dims` must be channel counts"),
    (EuclideanFlowConfig, {"backbone": "unet", "down_dims": (12, 24)}, r"divisible by n_groups=8"),
    (EuclideanFlowConfig, {"backbone": "unet", "kernel_size": 0}, r"`kernel_size` must be an integer >= 1"),
    (EuclideanFlowConfig, {"backbone": "unet", "diffusion_step_embed_dim": 2}, r"`diffusion_step_embed"),
]


@pytest.mark.parametrize(("cls", "overrides", "message"), UNUSABLE)
def test_unusable_sizes_are_refused(cls, overrides, message):
    with pytest.raises(PolicyConfigError, match=message):
        cls(device="cpu", **overrides)


def test_the_smallest_working_sizes_are_accepted_and_zero_is_refused():
    smallest = dict(dim=2, num_layers=1, num_heads=1, head_dim=1, num_query_points=1, num_value_points=1)
    ActionflowConfig(device="cpu", **smallest)
    for name in smallest:
        with pytest.raises(PolicyConfigError, match=f"`{name}` must be an integer >= 1, got 0"):
            ActionflowConfig(device="cpu", **{**smallest, name: 0})
    smallest = dict(n_layer=1, n_head=1, n_emb=4)
    EuclideanFlowConfig(device="cpu", **smallest)
    for name in smallest:
        with pytest.raises(PolicyConfigError, match=f"`{name}` must be an integer >= 1, got 0"):
            EuclideanFlowConfig(device="cpu", **{**smallest, name: 0})
    EuclideanFlowConfig(device="cpu", backbone="unet", down_dims=(4, 8), n_groups=4, kernel_size=1)


# The CLI cases of the issue: draccus instantiates the config, and the user must see its message.
CLI_CASES = [
    (["--policy.type=actionflow", "--policy.horizon=0"], "`horizon` must be an integer >= 1, got 0"),
    (["--policy.type=actionflow", "--policy.n_action_steps=20"], "`n_action_steps` must be in 1..horizon=16"),
    (["--policy.type=actionflow", "--policy.noise_sigma=-0.1"], "`noise_sigma` must be > 0, got -0.1"),
    (["--policy.type=actionflow", "--policy.n_obs_steps=0"], "`n_obs_steps` must be an integer >= 1, got 0"),
    (
        ["--policy.type=actionflow", '--policy.normalization_mapping={"STATE": "MEAN_STD"}'],
        "normalization_mapping['STATE'] must be IDENTITY for actionflow",
    ),
    (["--policy.type=euclidean_flow", "--policy.n_head=0"], "`n_head` must be an integer >= 1, got 0"),
]


def test_draccus_parse_carries_the_config_message():
    """What LeRobot's ``parser.wrap`` prints for a ``DecodingError`` is ``str(error)``; a LeRobot
    policy's own config error (the control) still goes through draccus unchanged."""
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig  # noqa: F401 (registers)

    def parse_error(args):
        with pytest.raises(DecodingError) as info:
            draccus.parse(TrainPipelineConfig, args=["--dataset.repo_id=local/x", *args])
        return str(info.value)

    hidden = [(args, msg) for args, msg in CLI_CASES if msg not in parse_error(args)]
    assert not hidden, f"messages not shown: {hidden}"
    control = parse_error(["--policy.type=diffusion", "--policy.vision_backbone=vgg"])
    assert "Couldn't instantiate class DiffusionConfig using the given arguments" in control


@pytest.mark.slow
def test_lerobot_train_prints_the_config_message(tmp_path):
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    args = [
        "--policy.type=actionflow", "--policy.horizon=0", "--policy.push_to_hub=false",
        "--dataset.repo_id=local/x", f"--output_dir={tmp_path / 'out'}", "--wandb.enable=false",
    ]  # fmt: skip
    out = subprocess.run([LEROBOT_TRAIN, *args], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode != 0
    assert "`horizon` must be an integer >= 1, got 0" in out.stderr, out.stderr[-3000:]
