"""``actionflow-train`` is ``lerobot-train`` on the in-memory source: same seed, same weights;
either CLI resumes the other's checkpoint."""

from __future__ import annotations

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from lerobot_actionflow.train import in_memory_training_data, pop_image_cache_flag
from tests.data.conftest import BIN, REPO_ID, cli_env
from tests.data.test_in_memory import mismatches

TINY_ACTIONFLOW = [
    "--policy.type=actionflow",
    "--policy.dim=32",
    "--policy.num_layers=1",
    "--policy.num_heads=2",
    "--policy.head_dim=8",
    "--policy.n_obs_steps=2",
    "--policy.horizon=8",
    "--policy.n_action_steps=4",
    "--policy.device=cpu",
    "--policy.push_to_hub=false",
]
LEROBOT_TRAIN = [str(BIN / "lerobot-train")]
ACTIONFLOW_TRAIN = [sys.executable, "-m", "lerobot_actionflow.train"]
SOURCE_LOG = "in-memory frame source"


def _train(cli: list[str], *args: str) -> str:
    proc = subprocess.run([*cli, *args], capture_output=True, text=True, timeout=400, env=cli_env())
    assert proc.returncode == 0, proc.stderr[-4000:]
    return proc.stdout + proc.stderr


def _weights(run: Path, step: int) -> dict:
    from safetensors.torch import load_file

    ckpts = sorted((run / "checkpoints").glob(f"*{step}"))
    assert ckpts, sorted(p.name for p in (run / "checkpoints").iterdir())
    return load_file(ckpts[-1] / "pretrained_model" / "model.safetensors")


def _assert_equal_weights(a: dict, b: dict) -> None:
    import torch

    assert a.keys() == b.keys()
    different = [k for k in a if not torch.equal(a[k], b[k])]
    assert not different, different[:5]


@pytest.mark.slow
def test_same_seed_same_weights_and_cross_resume(lift_dataset, tmp_path):
    runs = {"lerobot": tmp_path / "lerobot", "actionflow": tmp_path / "actionflow"}
    common = [
        f"--dataset.repo_id={REPO_ID}",
        f"--dataset.root={lift_dataset}",
        *TINY_ACTIONFLOW,
        "--wandb.enable=false",
        "--steps=2",
        "--save_freq=2",
        "--batch_size=8",
        "--num_workers=0",
        "--seed=3",
    ]
    # The two CLIs run side by side (independent processes: most of each is importing).
    with ThreadPoolExecutor(2) as pool:
        logs = dict(
            zip(
                runs,
                pool.map(
                    lambda name, cli: _train(cli, *common, f"--output_dir={runs[name]}"),
                    runs,
                    (LEROBOT_TRAIN, ACTIONFLOW_TRAIN),
                ),
                strict=True,
            )
        )
    assert SOURCE_LOG in logs["actionflow"] and SOURCE_LOG not in logs["lerobot"]
    first = {name: _weights(run, 2) for name, run in runs.items()}
    _assert_equal_weights(first["lerobot"], first["actionflow"])
    # Each CLI resumes the other's checkpoint for one more step, in the other's output folder.
    resumers = {"lerobot": ACTIONFLOW_TRAIN, "actionflow": LEROBOT_TRAIN}

    def resume(name: str) -> str:
        config = runs[name] / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
        return _train(resumers[name], "--resume=true", f"--config_path={config}", "--steps=3")

    with ThreadPoolExecutor(2) as pool:
        for name, log in zip(runs, pool.map(resume, runs), strict=True):
            ours = resumers[name] is ACTIONFLOW_TRAIN
            assert "Resuming data order" in log and (SOURCE_LOG in log) == ours
    resumed = {name: _weights(run, 3) for name, run in runs.items()}
    _assert_equal_weights(resumed["lerobot"], resumed["actionflow"])
    # control: the resumed step trained, so the equality above compares updated weights
    assert any(not v.equal(first["lerobot"][k]) for k, v in resumed["lerobot"].items())


def test_image_cache_flag_is_ours_and_removed():
    assert pop_image_cache_flag(["--steps=3", "--image_cache=true"]) == (True, ["--steps=3"])
    assert pop_image_cache_flag(["--image_cache"]) == (True, [])
    assert pop_image_cache_flag(["--image_cache", "false", "--steps=3"]) == (False, ["--steps=3"])
    assert pop_image_cache_flag(["--image_cache", "--steps=3"]) == (True, ["--steps=3"])
    other = "--image_cache_x=1"
    assert pop_image_cache_flag(["--image_cache=false", other]) == (False, [other])
    with pytest.raises(SystemExit, match="true or false, got 'maybe'"):
        pop_image_cache_flag(["--image_cache=maybe"])


def test_train_script_gets_in_memory_datasets_only_inside_the_block(lift_three_episodes):
    """The factory lerobot-train calls is wrapped within the block (train and held-out episodes
    both in memory, items equal to LeRobot's), and LeRobot's own function is back afterwards:
    importing the plugin or this module changes nothing."""
    import draccus
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.datasets import factory
    from lerobot.scripts import lerobot_train

    import lerobot_policy_actionflow  # noqa: F401
    from lerobot_actionflow.data.in_memory import InMemoryLeRobotDataset

    assert lerobot_train.make_train_eval_datasets is factory.make_train_eval_datasets
    args = [f"--dataset.repo_id={REPO_ID}", f"--dataset.root={lift_three_episodes}"]
    args += ["--dataset.eval_split=0.3", "--policy.type=euclidean_flow", "--policy.device=cpu"]
    cfg = draccus.parse(TrainPipelineConfig, args=args)
    plain = factory.make_train_eval_datasets(cfg)
    with in_memory_training_data():
        fast = lerobot_train.make_train_eval_datasets(cfg)
    assert lerobot_train.make_train_eval_datasets is factory.make_train_eval_datasets
    assert [d.episodes for d in fast] == [d.episodes for d in plain] == [[0, 1], [2]]
    for ours, theirs in zip(fast, plain, strict=True):
        assert isinstance(ours, InMemoryLeRobotDataset)
        assert not mismatches([theirs[i] for i in range(len(theirs))], ours[:])
