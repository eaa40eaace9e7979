"""`lerobot-eval --env.type=actionflow` rolls a policy out in 2 parallel envs and writes videos."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow.envs.tasks import get_task
from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig
from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
from lerobot_actionflow.policies.actionflow.processor_actionflow import make_actionflow_pre_post_processors


def _untrained_policy(task: str, path: Path) -> Path:
    """A tiny ActionFlow for the task's token count, saved with its processors, as a checkpoint."""
    n = get_task(task).num_tokens
    cfg = ActionflowConfig(
        input_features={
            "observation.poses": PolicyFeature(FeatureType.STATE, (n, 7)),
            "observation.state": PolicyFeature(FeatureType.STATE, (11,)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (10,))},
        dim=16, num_layers=1, num_heads=2, head_dim=4, num_query_points=2, num_value_points=2,
        horizon=8, n_action_steps=4, device="cpu", push_to_hub=False,
    )  # fmt: skip
    torch.manual_seed(0)
    ActionflowPolicy(cfg).save_pretrained(path)
    pre, post = make_actionflow_pre_post_processors(cfg)
    pre.save_pretrained(path)
    post.save_pretrained(path)
    return path


@pytest.mark.slow
@pytest.mark.parametrize("task", ["Lift", "Square"])
def test_lerobot_eval_runs_batched_episodes_and_records_videos(task, tmp_path):
    ckpt = _untrained_policy(task, tmp_path / "policy")
    out = tmp_path / "eval"
    cmd = [
        str(Path(sys.executable).with_name("lerobot-eval")), f"--policy.path={ckpt}", "--policy.device=cpu",
        "--env.type=actionflow", f"--env.task={task}", "--env.episode_length=12",
        "--env.visualization_height=64", "--env.visualization_width=64",
        "--eval.n_episodes=2", "--eval.batch_size=2", f"--output_dir={out}", "--seed=3",
    ]  # fmt: skip
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl"}
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600, cwd=tmp_path)
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 2
    videos = sorted(out.rglob("*.mp4"))
    assert len(videos) == 2 and all(v.stat().st_size > 0 for v in videos), videos
