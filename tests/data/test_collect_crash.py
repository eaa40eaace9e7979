"""``actionflow-collect`` after ``kill -9``: what a crash costs and what the rerun does.

Collection is deterministic per seed, so a dataset that was killed and resumed must hold the
same frames as a clean collection: the 2-episode ``lift_dataset`` fixture (seeds 0, 1) and, for
seed 2, a rollout of the expert in this process.
"""

from __future__ import annotations

import json
import random
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from lerobot_actionflow.data import staging as staging_mod
from lerobot_actionflow.data.collect import main
from lerobot_actionflow.data.staging import Staging, staging_dir
from lerobot_actionflow.schema import ACTION_KEY, ENV_STATE_KEY, POSES_KEY, STATE_KEY
from tests.data.conftest import REPO_ID, cli_env, collect_command, run_collect

KEYS = (POSES_KEY, STATE_KEY, ENV_STATE_KEY, ACTION_KEY)


def load(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(REPO_ID, root=root)


def episode_arrays(ds, episode: int) -> dict[str, np.ndarray]:
    """The schema arrays ``(T, ...)`` of one episode, read from the parquet data."""
    ep = np.asarray(ds.hf_dataset["episode_index"])
    return {k: np.stack([np.asarray(x) for x in ds.hf_dataset[k]])[ep == episode] for k in KEYS}


def assert_same_frames(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    for k in KEYS:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def clean_rollout_arrays(seed: int) -> dict[str, np.ndarray]:
    """The frames a clean collection stores for ``seed`` (Lift, no images)."""
    import gymnasium as gym

    import lerobot_actionflow.envs  # noqa: F401
    from lerobot_actionflow.data.features import frame_from_obs
    from lerobot_actionflow.experts import expert_class
    from lerobot_actionflow.experts.rollout import run_episode

    env = gym.make("lerobot_actionflow/Lift-v0", render_mode=None)
    try:
        ep = run_episode(env, expert_class("Lift")(env.unwrapped), seed)
    finally:
        env.close()
    assert ep.success
    frames = [frame_from_obs(o, a, "") for o, a in zip(ep.observations, ep.actions)]
    return {k: np.stack([f[k] for f in frames]) for k in KEYS}


def kill_at_random(root, episodes: int, rng: random.Random, window_s: float) -> float:
    """Start ``actionflow-collect``, wait until it has begun collecting (its staging state
    exists), ``kill -9`` it after a uniform random delay in ``[0, window_s]``; returns the delay."""
    proc = subprocess.Popen(
        collect_command(root, episodes), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=cli_env()
    )
    delay = rng.uniform(0.0, window_s)
    try:
        t0 = time.time()
        while not (staging_dir(root) / "state.json").exists() and proc.poll() is None:
            assert time.time() - t0 < 150, "collect did not start collecting"
            time.sleep(0.02)
        time.sleep(delay)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    return delay


def test_sigkill_at_random_moments_then_rerun_gives_the_clean_dataset(lift_dataset, tmp_path):
    """New dataset, killed twice at random moments, then the same command: exactly the requested
    episodes, frame for frame those of a clean collection."""
    rng = random.Random()
    root = tmp_path / "lift"
    delays = [kill_at_random(root, 2, rng, window_s=6.0) for _ in range(2)]
    proc = run_collect(root, 2)
    assert proc.returncode == 0, (delays, proc.stderr[-3000:])
    assert "2 episodes" in proc.stdout
    ds, clean = load(root), load(lift_dataset)
    assert ds.num_episodes == 2 and len(ds) == len(clean), delays
    for e in range(2):
        assert_same_frames(episode_arrays(ds, e), episode_arrays(clean, e))
    assert not staging_dir(root).exists()
    meta = json.loads((root / "meta" / "actionflow_collect.json").read_text())
    assert meta["seeds_kept"] == [0, 1] and meta["successes"] == 2


def test_sigkill_while_extending_keeps_the_old_episodes_and_resumes(lift_copy):
    """2 -> 3 episodes, killed at a random moment (the old dataset is intact after the kill);
    the rerun adds seed 2's episode exactly as a clean collection has it."""
    rng = random.Random()
    clean = load(lift_copy)
    old = [episode_arrays(clean, e) for e in range(2)]
    delay = kill_at_random(lift_copy, 3, rng, window_s=4.0)
    mid = load(lift_copy)  # after the kill: the old dataset or the extended one, never a broken one
    assert mid.num_episodes in (2, 3), delay
    proc = run_collect(lift_copy, 3)
    assert proc.returncode == 0, (delay, proc.stderr[-3000:])
    ds = load(lift_copy)
    assert ds.num_episodes == 3 and int(ds.meta.total_frames) == len(ds)
    for e in range(2):
        assert_same_frames(episode_arrays(ds, e), old[e])
    assert_same_frames(episode_arrays(ds, 2), clean_rollout_arrays(2))


class _Killed(BaseException):
    """Stands for ``kill -9``: nothing after it runs, no ``except Exception`` catches it."""


@pytest.mark.parametrize("crash_at", [0, 1, 2])
def test_crash_at_each_rename_of_the_commit_is_recovered(lift_copy, monkeypatch, crash_at):
    """A staged episode (episode 1's frames as attempt 2) is committed into a 2-episode
    dataset; the commit stops before rename ``crash_at`` (merged / root -> previous / merged ->
    root). The dataset is then the old or the new one, and recovery plus a rerun's commit
    give 3 episodes exactly once."""
    from lerobot_actionflow.data.collect import _check_target, _target_meta
    from lerobot_actionflow.data.features import schema_features
    from lerobot_actionflow.envs.tasks import get_task

    root, ds = lift_copy, load(lift_copy)
    ep1 = episode_arrays(ds, 1)
    frames = [
        {**{k: v[t] for k, v in ep1.items()}, "task": ds.meta.tasks.index[0]}
        for t in range(len(ep1[ACTION_KEY]))
    ]
    target = json.loads((root / "meta" / "actionflow_collect.json").read_text())
    meta = {**target, "seeds_kept": [0, 1, 2], "successes": 3, "attempts": 3, "next_attempt": 3}
    features = schema_features(2)
    st = Staging(root, REPO_ID)
    st.write_episode(2, frames)
    st.write_state(meta)
    calls = []

    def rename(src, dst):
        if len(calls) == crash_at:
            raise _Killed
        calls.append((src, dst))
        shutil.move(src, dst)

    monkeypatch.setattr(staging_mod, "_rename", rename)
    with pytest.raises(_Killed):
        st.commit(meta, target, features, 20, False)
    monkeypatch.undo()
    assert root.exists() == (crash_at != 2)
    st.recover(_target_meta)  # what the rerun does first
    now = _check_target(root, REPO_ID, get_task("Lift"), (), 0, features, None)
    st.commit(meta, now, features, 20, False)
    out = load(root)
    assert out.num_episodes == 3
    assert_same_frames(episode_arrays(out, 2), ep1)
    assert not st.pending()


def _drop_meta_episodes(root: Path) -> None:
    shutil.rmtree(root / "meta" / "episodes")  # an in-place writer killed before its footer


def _claim_one_more_episode(root: Path) -> None:
    info_path = root / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    info["total_episodes"] += 1
    info_path.write_text(json.dumps(info))


@pytest.mark.parametrize("break_folder", [_drop_meta_episodes, _claim_one_more_episode])
def test_folder_left_inconsistent_by_a_crash_is_refused_with_what_to_do(lift_copy, capsys, break_folder):
    """A dataset a crash left inconsistent: exit 2, a message saying what to do, the folder
    untouched; never reported complete."""
    break_folder(lift_copy)
    before = sorted(p.relative_to(lift_copy) for p in lift_copy.rglob("*"))
    args = [
        "--task",
        "Lift",
        "--episodes",
        "2",
        "--root",
        str(lift_copy),
        "--repo-id",
        REPO_ID,
        "--no-progress",
    ]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "inconsistent" in err or "does not load" in err
    assert "move it aside" in err and "same command" in err
    assert sorted(p.relative_to(lift_copy) for p in lift_copy.rglob("*")) == before


def test_root_that_is_a_file_is_an_error_not_a_traceback(tmp_path, capsys):
    f = tmp_path / "lift"
    f.write_text("not a dataset")
    assert main(["--task", "Lift", "--episodes", "1", "--root", str(f), "--no-progress"]) == 2
    assert "is a file" in capsys.readouterr().err
    assert f.read_text() == "not a dataset"
