"""Shared fixtures: one small Lift dataset collected by the CLI, reused by the data tests."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent
REPO_ID = "local/lift_test"


def cli_env() -> dict[str, str]:
    return {**os.environ, "HF_HUB_OFFLINE": "1", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}


def collect_command(root: Path, episodes: int, *extra: str) -> list[str]:
    """``actionflow-collect`` on Lift into ``root`` (the tests' repo id, no progress bar)."""
    return [
        str(BIN / "actionflow-collect"),
        "--task",
        "Lift",
        "--episodes",
        str(episodes),
        "--root",
        str(root),
        "--repo-id",
        REPO_ID,
        "--no-progress",
        *extra,
    ]


def run_collect(root: Path, episodes: int, *extra: str, timeout: int = 180) -> subprocess.CompletedProcess:
    cmd = collect_command(root, episodes, *extra)
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=cli_env())


@pytest.fixture(scope="session")
def lift_dataset(tmp_path_factory) -> Path:
    """A 2-episode Lift dataset written by ``actionflow-collect`` (read-only for the tests: copy it
    before changing it)."""
    root = tmp_path_factory.mktemp("collect") / "lift"
    proc = run_collect(root, 2)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return root


@pytest.fixture(scope="session")
def lift_three_episodes(tmp_path_factory) -> Path:
    """A 3-episode Lift dataset written by ``actionflow-collect`` (read-only for the tests): one
    episode with both boundaries inside the dataset."""
    root = tmp_path_factory.mktemp("collect3") / "lift"
    proc = run_collect(root, 3)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return root


@pytest.fixture
def lift_copy(lift_dataset, tmp_path) -> Path:
    dst = tmp_path / "lift"
    shutil.copytree(lift_dataset, dst)
    return dst
