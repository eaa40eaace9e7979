"""The latency-honest evaluation on a real task with a tiny untrained ActionFlow checkpoint."""

import json

import numpy as np
import pytest
import torch
from lerobot.configs.default import EvalConfig
from lerobot.configs.policies import PreTrainedConfig
from lerobot.envs.factory import make_env_pre_post_processors
from lerobot.policies.factory import make_policy, make_pre_post_processors
from lerobot.scripts.lerobot_eval import rollout

from lerobot_actionflow.envs.configuration import ActionFlowEnvConfig
from lerobot_actionflow.evaluation import latency, latency_sweep
from lerobot_actionflow.evaluation.latency import ChunkLatency
from lerobot_actionflow.evaluation.latency_hold import make_latency_envs
from lerobot_actionflow.evaluation.latency_sweep import LatencySweepConfig, load_previous, run_latency_sweep
from lerobot_actionflow.evaluation.provenance import DIGEST_KEY, weights_digest
from lerobot_actionflow.evaluation.untrained import save_untrained_actionflow

STEPS = 6  # control steps per episode


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    return save_untrained_actionflow("Lift", tmp_path_factory.mktemp("ckpt") / "pretrained_model")


def test_zero_latency_gives_exactly_the_ordinary_evaluations_actions(checkpoint):
    env_cfg = ActionFlowEnvConfig(task="Lift", episode_length=STEPS)
    policy_cfg = PreTrainedConfig.from_pretrained(checkpoint)
    policy_cfg.pretrained_path = checkpoint
    policy = make_policy(cfg=policy_cfg, env_cfg=env_cfg).eval()
    processors = (
        *make_env_pre_post_processors(env_cfg=env_cfg, policy_cfg=policy_cfg),
        *make_pre_post_processors(policy_cfg=policy_cfg, pretrained_path=str(checkpoint)),
    )
    plain = env_cfg.create_envs(n_envs=1)["actionflow"][0]
    held = make_latency_envs(env_cfg, n_envs=1)
    try:
        torch.manual_seed(0)
        ordinary = rollout(plain, policy, *processors, seeds=[3])["action"]
        actions = {}
        for latency in (0.0, 0.1):
            torch.manual_seed(0)
            with ChunkLatency(policy, held, control_period_s=0.05, latency_s=latency) as hook:
                actions[latency] = rollout(held, policy, *processors, seeds=[3])["action"]
            (record,) = held.call("pop_episode_records")[0]
            assert record["control_steps"] == STEPS
            assert record["held_steps"] == len(hook.holds) * (0 if latency == 0 else 2)
    finally:
        plain.close()
        held.close()
    assert policy.select_action.__func__ is type(policy).select_action  # the hook is removed
    assert torch.equal(actions[0.0], ordinary)
    # control: with a latency the env moved on while the policy thought, so it saw other states
    assert actions[0.1].shape[1] < ordinary.shape[1] or not torch.equal(actions[0.1], ordinary)


def test_latency_sweep_writes_every_cell(checkpoint, tmp_path):
    cfg = LatencySweepConfig(
        env=ActionFlowEnvConfig(task="Lift", episode_length=STEPS),
        checkpoints=[str(checkpoint)],
        latencies_ms=[0, 100],
        modes=["plain", "scheme", "rtc"],
        eval=EvalConfig(n_episodes=1, batch_size=1),
        output_dir=tmp_path,
    )
    rows = run_latency_sweep(cfg)
    saved = json.loads((tmp_path / "latency_results.json").read_text())
    assert len(saved["cells"]) == len(rows) == 6
    for row in saved["cells"]:
        assert row["n_episodes"] == 1 and row["episodes"][0]["control_steps"] == STEPS
        assert row["pc_success"] == row["lerobot_pc_success"]
        assert row["mean_hold_steps"] == (0 if row["latency_ms"] == 0 else 2)
        figures = [row["max_position_jump_m"], row["max_rotation_jump_rad"], row["mean_jerk_m2"]]
        assert np.isfinite(figures).all()
        # how far the episode got: Lift's sub-goals, in task order, and the arm's joint margin
        episode = row["episodes"][0]
        assert list(episode["subgoals_reached"]) == ["cube_grasped", "cube_lifted"]
        assert list(row["pc_subgoals"]) == list(episode["subgoals_reached"])
        assert np.isfinite(episode["min_joint_margin_rad"])
        assert row["mean_min_joint_margin_rad"] == episode["min_joint_margin_rad"]
    table = (tmp_path / "latency_results.md").read_text()
    assert "100 ms" in table and "scheme" in table and "rtc" in table
    assert "| cube_grasped | cube_lifted |" in table
    pytest.importorskip("matplotlib")
    assert (tmp_path / "latency_success.png").stat().st_size > 0


def _sweep_config(checkpoint, out, latencies, n_episodes=1, **env):
    return LatencySweepConfig(
        env=ActionFlowEnvConfig(task="Lift", episode_length=STEPS, **env),
        checkpoints=[str(checkpoint)],
        latencies_ms=latencies,
        modes=["plain"],
        eval=EvalConfig(n_episodes=n_episodes, batch_size=1),
        output_dir=out,
    )


def test_a_sweep_resumes_keeping_the_stored_cells_and_running_only_new_ones(
    checkpoint, tmp_path, monkeypatch
):
    first = run_latency_sweep(_sweep_config(checkpoint, tmp_path, [0]))
    resumed = run_latency_sweep(_sweep_config(checkpoint, tmp_path, [0, 100]))
    assert [r["latency_ms"] for r in resumed] == [0.0, 100.0]
    assert resumed[0] == json.loads(json.dumps(first[0]))  # kept as stored, not run again
    saved = json.loads((tmp_path / "latency_results.json").read_text())
    assert saved["settings"]["complete"] and len(saved["cells"]) == 2

    def no_policy(*args, **kwargs):
        raise AssertionError("a sweep with every cell stored loaded a policy")

    monkeypatch.setattr("lerobot.policies.factory.make_policy", no_policy)
    assert run_latency_sweep(_sweep_config(checkpoint, tmp_path, [100, 0])) == resumed
    # the same checkpoint typed otherwise, and a latency given twice
    same = f"{checkpoint.parent}/../{checkpoint.parent.name}/{checkpoint.name}/"
    assert run_latency_sweep(_sweep_config(same, tmp_path, [100, 100.0, 0])) == resumed
    with pytest.raises(AssertionError, match="loaded a policy"):  # control: a new cell does load it
        run_latency_sweep(_sweep_config(checkpoint, tmp_path, [200]))
    # the folder's weights are not the ones the stored cells measured (a run trained again there):
    # a new cell is refused before anything is loaded, and the stored file is kept
    path = tmp_path / "latency_results.json"
    saved = json.loads(path.read_text())
    assert {c[DIGEST_KEY] for c in saved["cells"]} == {weights_digest(checkpoint)}
    for cell in saved["cells"]:
        cell[DIGEST_KEY] = "0" * 64
    path.write_text(json.dumps(saved))
    with pytest.raises(ValueError, match="trained again"):
        run_latency_sweep(_sweep_config(checkpoint, tmp_path, [200]))
    assert json.loads(path.read_text()) == saved


def test_a_sweep_with_other_settings_is_refused_and_the_stored_file_kept(tmp_path):
    settings = json.loads(json.dumps(latency_sweep._settings(_sweep_config("ckpt", tmp_path, [0]))))
    stored = {"settings": {**settings, "complete": True}, "cells": [{"checkpoint": "ckpt"}]}
    path = tmp_path / "latency_results.json"
    path.write_text(json.dumps(stored))
    with pytest.raises(ValueError, match="n_episodes: stored 1, now 20"):
        run_latency_sweep(_sweep_config("ckpt", tmp_path, [0], n_episodes=20))
    with pytest.raises(
        ValueError, match=r"env: stored .*'scene_yaw': \[0\.0, 0\.0\].*'scene_yaw': \[-0\.5, 0\.5\]"
    ):
        run_latency_sweep(_sweep_config("ckpt", tmp_path, [0], scene_yaw=(-0.5, 0.5)))
    assert json.loads(path.read_text()) == stored
    assert load_previous(_sweep_config("ckpt", tmp_path, [0, 800])) == stored["cells"]  # control
    path.write_text("{not json")
    with pytest.raises(ValueError, match="is not a latency sweep's results"):
        load_previous(_sweep_config("ckpt", tmp_path, [0]))


def test_sweeps_side_by_side_into_one_folder_keep_each_others_cells(checkpoint, tmp_path, monkeypatch):
    evaluate, evaluated = latency.evaluate_with_latency, []

    def evaluate_while_another_sweep_runs(*args, latency_s, **kwargs):
        evaluated.append(latency_s)
        if len(evaluated) == 1:  # during this sweep's first cell, a second sweep runs whole
            run_latency_sweep(_sweep_config(checkpoint, tmp_path, [100]))
        return evaluate(*args, latency_s=latency_s, **kwargs)

    monkeypatch.setattr(latency, "evaluate_with_latency", evaluate_while_another_sweep_runs)
    rows = run_latency_sweep(_sweep_config(checkpoint, tmp_path, [0, 100]))
    assert evaluated == [0.0, 0.1]  # the second sweep's cell was not evaluated again
    saved = json.loads((tmp_path / "latency_results.json").read_text())
    assert [c["latency_ms"] for c in saved["cells"]] == [r["latency_ms"] for r in rows] == [100.0, 0.0]
    assert saved["settings"]["complete"]


def test_the_held_target_at_an_episodes_start_keeps_the_arm_still():
    import gymnasium as gym

    from lerobot_actionflow.evaluation.latency_hold import idle_target
    from lerobot_actionflow.rotations import geodesic_distance

    env = gym.make("lerobot_actionflow/Lift-v0", max_episode_steps=STEPS)
    try:
        obs, _ = env.reset(seed=0)
        p0, r0 = env.unwrapped.eef_pose()
        for _ in range(STEPS - 1):
            env.step(idle_target(obs))
        p1, r1 = env.unwrapped.eef_pose()
        assert np.linalg.norm(p1 - p0) < 1e-5 and geodesic_distance(r0, r1) < 1e-5
        # control: a target 5 cm away does move it
        moved = idle_target(obs)
        moved[2] += 0.05
        env.step(moved)
        assert np.linalg.norm(env.unwrapped.eef_pose()[0] - p1) > 1e-3
    finally:
        env.close()
