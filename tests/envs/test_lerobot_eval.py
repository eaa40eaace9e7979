"""`lerobot-eval --env.type=actionflow` rolls a policy out in a batch of 2 envs and writes videos.

Lift runs in LeRobot's default asynchronous vector env (one worker process per env); Square in
the synchronous one, which costs half the time and covers the in-process path.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_actionflow.evaluation.untrained import save_untrained_actionflow


@pytest.mark.slow
@pytest.mark.parametrize(("task", "async_envs"), [("Lift", True), ("Square", False)])
def test_lerobot_eval_runs_batched_episodes_and_records_videos(task, async_envs, tmp_path):
    ckpt = save_untrained_actionflow(task, tmp_path / "policy")
    out = tmp_path / "eval"
    cmd = [
        str(Path(sys.executable).with_name("lerobot-eval")), f"--policy.path={ckpt}", "--policy.device=cpu",
        "--env.type=actionflow", f"--env.task={task}", "--env.episode_length=12",
        "--env.visualization_height=64", "--env.visualization_width=64",
        "--eval.n_episodes=2", "--eval.batch_size=2", f"--output_dir={out}", "--seed=3",
        f"--eval.use_async_envs={str(async_envs).lower()}",
    ]  # fmt: skip
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl"}
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600, cwd=tmp_path)
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 2
    videos = sorted(out.rglob("*.mp4"))
    assert len(videos) == 2 and all(v.stat().st_size > 0 for v in videos), videos
