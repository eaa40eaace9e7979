"""The ready lerobot-train configs parse into LeRobot's TrainPipelineConfig and are up to date."""

import importlib.util
import json
from pathlib import Path

import draccus
import pytest

ROOT = Path(__file__).resolve().parents[2] / "configs"
CONFIGS = sorted((ROOT / "train").glob("*/*.json"))


def _generator():
    spec = importlib.util.spec_from_file_location("make_configs", ROOT / "make_configs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_policy_and_task_has_a_config():
    gen = _generator()
    assert len(CONFIGS) == len(gen.POLICIES) * len(gen.TASKS)
    for path in CONFIGS:
        assert json.loads(path.read_text()) == gen.config(path.parent.name, path.stem), f"{path} is stale"


# Configs differ across tasks only in names (checked above against the generator), so parsing
# two tasks per policy covers the structure; every task name is checked against the env registry.
PARSED = [p for p in CONFIGS if p.stem in ("Lift", "StackThree_D1")]


def test_every_config_task_is_a_registered_env_task():
    from lerobot_actionflow.envs.tasks import get_task

    for task in _generator().TASKS:
        assert get_task(task).name == task


@pytest.mark.parametrize("path", PARSED, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_config_parses_into_lerobot_train_config(path):
    import lerobot.policies  # noqa: F401  (registers LeRobot's own policy types, as lerobot-train does)
    from lerobot.configs.train import TrainPipelineConfig

    import lerobot_policy_actionflow  # noqa: F401  (registers the policy and env types)

    cfg = draccus.parse(TrainPipelineConfig, config_path=str(path), args=["--policy.device=cpu"])
    assert cfg.policy.type == path.parent.name
    assert cfg.env.type == "actionflow" and cfg.env.task == path.stem
    assert (cfg.policy.n_obs_steps, cfg.policy.horizon, cfg.policy.n_action_steps) == (2, 16, 8)
    assert cfg.dataset.repo_id == f"local/{path.stem}"
