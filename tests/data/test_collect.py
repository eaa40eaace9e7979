"""``actionflow-collect``: schema, metadata, resume/extend, clean interruption."""

from __future__ import annotations

import json
import signal
import subprocess
import time

import numpy as np
import pytest

from lerobot_actionflow.data.collect import main
from lerobot_actionflow.data.staging import staging_dir
from lerobot_actionflow.schema import ACTION_KEY, POSES_KEY, STATE_KEY, feature_shapes
from tests.data.conftest import REPO_ID, cli_env, collect_command, run_collect


def load(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(REPO_ID, root=root)


def test_collected_dataset_has_schema_keys_and_shapes(lift_dataset):
    ds = load(lift_dataset)
    assert ds.num_episodes == 2
    assert ds.fps == 20
    item = ds[0]
    assert {k: tuple(item[k].shape) for k in feature_shapes(2)} == feature_shapes(2)  # EEF + cube
    assert item["task"] == "Lift the red cube off the table."
    # Unit quaternions, and the state's EEF position equals pose row 0.
    poses = np.stack([ds[i][POSES_KEY].numpy() for i in range(len(ds))])
    np.testing.assert_allclose(np.linalg.norm(poses[..., 3:], axis=-1), 1.0, atol=1e-5)
    states = np.stack([ds[i][STATE_KEY].numpy() for i in range(len(ds))])
    np.testing.assert_allclose(states[:, :3], poses[:, 0, :3], atol=1e-6)
    # Expert actions: valid 6D rotations, the gripper opens and later closes in each episode.
    actions = np.stack([ds[i][ACTION_KEY].numpy() for i in range(len(ds))])
    np.testing.assert_allclose(np.linalg.norm(actions[:, 3:6], axis=-1), 1.0, atol=1e-5)
    episode = np.array([int(ds[i]["episode_index"]) for i in range(len(ds))])
    for e in (0, 1):
        g = actions[episode == e, 9]
        assert g[0] == -1.0 and g[-1] == 1.0


def test_collect_metadata_records_task_expert_seeds(lift_dataset):
    meta = json.loads((lift_dataset / "meta" / "actionflow_collect.json").read_text())
    assert meta["task"] == "Lift"
    assert meta["expert_version"].startswith("lift-")
    assert meta["successes"] == 2 and len(meta["seeds_kept"]) == 2
    assert meta["attempts"] == meta["successes"] + len(meta["seeds_failed"])
    assert meta["success_rate"] == pytest.approx(meta["successes"] / meta["attempts"])


def test_rerun_extends_to_the_target_total(lift_copy):
    before = json.loads((lift_copy / "meta" / "actionflow_collect.json").read_text())
    proc = run_collect(lift_copy, 3)
    assert proc.returncode == 0, proc.stderr[-3000:]
    ds = load(lift_copy)
    assert ds.num_episodes == 3
    meta = json.loads((lift_copy / "meta" / "actionflow_collect.json").read_text())
    # New seeds only: the resumed run continues after the attempts already made.
    assert meta["seeds_kept"][:2] == before["seeds_kept"]
    assert len(set(meta["seeds_kept"])) == 3
    assert min(meta["seeds_kept"][2:]) >= before["next_attempt"]
    # The same command again is a no-op (in-process: the same entry point).
    assert main(_args(lift_copy, 3)) == 0
    assert load(lift_copy).num_episodes == 3
    assert (
        json.loads((lift_copy / "meta" / "actionflow_collect.json").read_text())["attempts"]
        == meta["attempts"]
    )


def _args(root, episodes, *extra):
    return ["--task", "Lift", "--episodes", str(episodes), "--root", str(root), "--repo-id", REPO_ID,
            "--no-progress", *extra]  # fmt: skip


def test_rerun_with_other_settings_is_refused(lift_copy, capsys):
    assert main(_args(lift_copy, 3, "--seed", "7")) == 2
    assert "seed" in capsys.readouterr().err
    assert load(lift_copy).num_episodes == 2


def _wait_for_first_episode(proc, root, timeout=150.0):
    meta = staging_dir(root) / "state.json"  # the run's state, replaced after every attempt
    t0 = time.time()
    while time.time() - t0 < timeout:
        if proc.poll() is not None:
            raise AssertionError(f"collect ended early: {proc.stderr.read()[-3000:]}")
        if meta.exists() and json.loads(meta.read_text())["successes"] >= 1:
            return
        time.sleep(0.05)
    raise AssertionError("no episode saved in time")


def _interrupted_collect(root, episodes: int, wait_until) -> subprocess.Popen:
    """Start ``actionflow-collect`` on Lift, send SIGINT once ``wait_until(proc)`` returns, and
    return the finished process (killed if it does not exit)."""
    cmd = collect_command(root, episodes)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=cli_env())
    try:
        wait_until(proc)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc


def test_sigint_after_first_episode_leaves_a_loadable_dataset(tmp_path):
    root = tmp_path / "lift"
    proc = _interrupted_collect(root, 50, lambda p: _wait_for_first_episode(p, root))
    assert proc.returncode == 130, proc.stderr.read()[-3000:]
    ds = load(root)
    meta = json.loads((root / "meta" / "actionflow_collect.json").read_text())
    assert 1 <= ds.num_episodes < 50
    assert ds.num_episodes == meta["successes"]
    assert meta["interrupted"] is True
    assert len(ds) == int(ds.meta.total_frames)
    ds[len(ds) - 1]  # the last frame of the last episode reads


def test_sigint_before_any_episode_leaves_no_folder(tmp_path):
    root = tmp_path / "lift"

    def collecting(proc):  # the run has begun collecting, no episode saved yet
        t0 = time.time()
        while not (staging_dir(root) / "state.json").exists():
            assert proc.poll() is None and time.time() - t0 < 120, "collect did not start collecting"
            time.sleep(0.01)

    proc = _interrupted_collect(root, 5, collecting)
    assert proc.returncode == 130
    assert not root.exists() and not staging_dir(root).exists()


def test_unknown_task_without_expert_fails_cleanly(tmp_path, capsys):
    root = tmp_path / "x"
    assert main(["--task", "NoSuchTask", "--episodes", "1", "--root", str(root)]) == 2
    assert "NoSuchTask" in capsys.readouterr().err
    assert not root.exists()
