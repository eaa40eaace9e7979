"""The delay arithmetic at chunk boundaries: which env steps hold which action.

A fake env records every target it receives; a scripted chunking policy encodes, in the x
coordinate of each action, ``10 * chunk + index``. The hold target at an episode's start (the
arm's current pose) has x = -1.
"""

from collections import deque
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.vector import AutoresetMode

from lerobot_actionflow.envs.progress import MIN_JOINT_MARGIN, PROGRESS_INFO_KEY, SUBGOALS_REACHED
from lerobot_actionflow.evaluation.latency import (
    ChunkLatency,
    Scheme,
    configure_execution,
    hold_steps,
    summarize,
)
from lerobot_actionflow.evaluation.latency_hold import LatencyHoldWrapper
from lerobot_actionflow.policies.execution import ExecutionOptions, execution_window
from lerobot_actionflow.schema import ACTION_DIM, ACTION_KEY, ENV_AGENT_POS, STATE_DIM

IDLE_X = -1.0
ROT6D_IDENTITY = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]


class RecordingEnv(gym.Env):
    """Episodes of ``length`` steps; the EEF sits at x = -1; every target's x is recorded."""

    def __init__(self, length: int):
        self.length = length
        self.observation_space = gym.spaces.Dict(
            {ENV_AGENT_POS: gym.spaces.Box(-np.inf, np.inf, (STATE_DIM,), np.float64)}
        )
        self.action_space = gym.spaces.Box(-np.inf, np.inf, (ACTION_DIM,), np.float64)
        self.xs: list[float] = []

    def _obs(self):
        pos = np.zeros(STATE_DIM)
        pos[0], pos[3:9] = IDLE_X, ROT6D_IDENTITY
        return {ENV_AGENT_POS: pos}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.xs, self.t = [], 0
        return self._obs(), {"is_success": False}

    def step(self, action):
        self.xs.append(float(action[0]))
        self.t += 1
        return self._obs(), 0.0, False, self.t >= self.length, {"is_success": False}


def _action(x: float) -> torch.Tensor:
    a = torch.zeros(ACTION_DIM)
    a[0], a[3:9] = x, torch.tensor(ROT6D_IDENTITY)
    return a


class ScriptedPolicy(torch.nn.Module):
    """Chunks of ``horizon`` actions, x = 10 * chunk + index; executes ``n_action_steps`` from
    ``skip`` on (the policies' :func:`execution_window`); RTC: the first ``inference_delay``
    actions are the leftover's."""

    def __init__(self, horizon: int, n_action_steps: int, skip: int = 0):
        super().__init__()
        self.config = SimpleNamespace(type="scripted", n_action_steps=n_action_steps, n_obs_steps=1)
        self.horizon, self.skip = horizon, skip
        self.reset()

    def supports_rtc(self) -> bool:
        return True

    def reset(self):
        self._queues = {ACTION_KEY: deque()}
        self.chunks = 0

    def predict_action_chunk(self, batch, inference_delay=None, prev_chunk_left_over=None):
        chunk = torch.stack([_action(10.0 * self.chunks + i) for i in range(self.horizon)])[None]
        self.chunks += 1
        if prev_chunk_left_over is not None and inference_delay:
            d = min(inference_delay, prev_chunk_left_over.shape[1])
            chunk[:, :d] = prev_chunk_left_over[:, :d]
        return chunk

    def select_action(self, batch):
        if not self._queues[ACTION_KEY]:
            chunk = self.predict_action_chunk(batch)
            window = execution_window(self.horizon, self.skip, self.config.n_action_steps)
            self._queues[ACTION_KEY].extend(chunk[:, window].transpose(0, 1))
        return self._queues[ACTION_KEY].popleft()


def run(policy, latency_s, period, length, rtc=False):
    """A rollout as LeRobot's: select_action, then one env step, until the episode ends."""
    vec = gym.vector.SyncVectorEnv(
        [lambda: LatencyHoldWrapper(RecordingEnv(length))], autoreset_mode=AutoresetMode.SAME_STEP
    )
    hook = ChunkLatency(policy, vec, period, latency_s, rtc=rtc, to_env_action=lambda a: a.numpy())
    with hook:
        policy.reset()
        vec.reset(seed=0)
        done = False
        while not done:
            action = policy.select_action({})
            _, _, term, trunc, _ = vec.step(action.numpy())
            done = bool(term[0] or trunc[0])
    xs = vec.envs[0].unwrapped.xs
    (record,) = vec.call("pop_episode_records")[0]
    return xs, record, hook


I = IDLE_X


@pytest.mark.parametrize(
    "latency_s, period, k",
    [(0.0, 0.05, 0), (0.01, 0.05, 1), (0.05, 0.05, 1), (0.051, 0.05, 2), (0.08, 0.04, 2), (0.1, 0.04, 3),
     (0.2, 0.05, 4), (0.8, 0.05, 16), (0.8, 0.04, 20)],
)  # fmt: skip
def test_hold_steps_is_ceil_of_latency_over_period(latency_s, period, k):
    assert hold_steps(latency_s, period) == k


@pytest.mark.parametrize("bad", [(-0.1, 0.05), (0.1, 0.0), (float("nan"), 0.05), (0.1, -1.0)])
def test_hold_steps_refuses_bad_values(bad):
    with pytest.raises(ValueError, match="seconds"):
        hold_steps(*bad)


@pytest.mark.parametrize(
    "latency_s, period, expected, held",
    [
        (0.0, 0.05, [0, 1, 10, 11, 20, 21, 30], 0),
        (0.1, 0.05, [I, I, 0, 1, 1, 1, 10, 11, 11, 11, 20], 6),  # k = 2: the previous target held
        (0.1, 0.04, [I, I, I, 0, 1, 1, 1, 1, 10, 11], 6),  # k = 3
        (0.03, 0.05, [I, 0, 1, 1, 10, 11, 11, 20], 3),  # k = 1
    ],
)
def test_plain_chunks_start_k_steps_late_holding_the_previous_target(latency_s, period, expected, held):
    xs, record, hook = run(ScriptedPolicy(horizon=4, n_action_steps=2), latency_s, period, len(expected))
    assert xs == expected
    assert (record["control_steps"], record["held_steps"]) == (len(expected), held)
    assert set(hook.holds) == {hold_steps(latency_s, period)}


def test_latency_aware_skipping_lines_up_with_the_held_steps():
    # k = 2 held steps, and the policy skips 2: action i of a chunk lands i steps after its
    # observation (chunk c is observed at step 4c: holds 2, executes 2).
    xs, _, _ = run(ScriptedPolicy(horizon=6, n_action_steps=2, skip=2), 0.1, 0.05, 12)
    assert xs == [I, I, 2, 3, 3, 3, 12, 13, 13, 13, 22, 23]
    observed_at = {c: 4 * c for c in range(3)}
    for step, x in enumerate(xs):
        if x != I and step % 4 >= 2:
            c, i = divmod(int(x), 10)
            assert step == observed_at[c] + i


def test_simulated_rtc_plays_the_leftover_during_the_delay():
    xs, record, _ = run(ScriptedPolicy(horizon=6, n_action_steps=2), 0.1, 0.05, 12, rtc=True)
    # chunk 0 (no leftover): idle 2, then its actions 2, 3; chunk 1 is observed at step 4 of
    # chunk 0: its leftover 4, 5 is played (and frozen in chunk 1), then chunk 1's 12, 13; ...
    assert xs == [I, I, 2, 3, 4, 5, 12, 13, 14, 15, 22, 23]
    assert record["held_steps"] == 6


def test_an_episode_that_ends_during_the_hold_ends_there():
    xs, record, _ = run(ScriptedPolicy(horizon=4, n_action_steps=2), 0.1, 0.05, 5)
    assert xs == [I, I, 0, 1, 1]
    assert record["control_steps"] == 5 and record["chunks"] == 2


def test_zero_latency_hook_changes_no_action():
    a, _, _ = run(ScriptedPolicy(horizon=4, n_action_steps=2), 0.0, 0.05, 9)
    assert a == [0, 1, 10, 11, 20, 21, 30, 31, 40]


def test_pending_hold_of_a_wrong_shape_is_refused():
    env = LatencyHoldWrapper(RecordingEnv(4))
    env.reset(seed=0)
    env.pending_hold = np.zeros((2, 3))
    with pytest.raises(ValueError, match=f"\\(k, {ACTION_DIM}\\)"):
        env.step(_action(0).numpy())


@pytest.mark.parametrize(
    "latency_s, period", [(0.0, 0.05), (0.05, 0.05), (0.1, 0.04), (0.2, 0.05), (0.8, 0.05)]
)
def test_scheme_configures_the_policy_to_skip_what_the_env_holds(latency_s, period):
    from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig

    config = ActionflowConfig(horizon=16, n_action_steps=8, guide_to_previous_chunk=True)
    policy = SimpleNamespace(config=config, supports_rtc=lambda: True)
    configure_execution(policy, "scheme", latency_s, period, Scheme(2, 0.5), trained_action_steps=8)
    window = ExecutionOptions.from_config(policy.config).window(16, policy.config.n_action_steps)
    assert window.start == min(hold_steps(latency_s, period), 15)
    assert policy.config.n_action_steps == 2 and policy.config.target_smoothing == 0.5
    configure_execution(policy, "plain", latency_s, period, Scheme(2, 0.5), trained_action_steps=8)
    window = ExecutionOptions.from_config(policy.config).window(16, policy.config.n_action_steps)
    assert (window.start, window.stop, policy.config.target_smoothing) == (0, 8, 1.0)
    assert not policy.config.guide_to_previous_chunk  # a guided checkpoint's chunks are plain here


def test_scheme_needs_a_flow_policy():
    config = SimpleNamespace(type="diffusion", n_action_steps=8)
    policy = SimpleNamespace(config=config, supports_rtc=lambda: False)
    with pytest.raises(ValueError, match="flow policy"):
        configure_execution(policy, "scheme", 0.1, 0.05, Scheme(), 8)
    with pytest.raises(ValueError, match="real-time chunking"):
        configure_execution(policy, "rtc", 0.1, 0.05, Scheme(), 8)
    configure_execution(policy, "plain", 0.1, 0.05, Scheme(), 8)  # holds only: any policy


class SlowPolicy(ScriptedPolicy):
    """Takes ``seconds`` of wall clock for each chunk."""

    def __init__(self, seconds: float, **kw):
        super().__init__(**kw)
        self.seconds = seconds

    def predict_action_chunk(self, batch, **kw):
        import time

        time.sleep(self.seconds)
        return super().predict_action_chunk(batch, **kw)


def test_a_measured_latency_holds_the_steps_the_inference_took():
    # 0.3 s at 0.25 s per step: 2 steps (sleep overshoots, never undershoots; a margin of 0.2 s
    # before it would be 3)
    xs, _, hook = run(SlowPolicy(0.3, horizon=4, n_action_steps=2), None, 0.25, 6)
    assert set(hook.holds) == {2}
    assert xs == [I, I, 0, 1, 1, 1]


class ProgressEnv(RecordingEnv):
    """A RecordingEnv whose info carries a progress record (as EpisodeProgress adds it): sub-goal
    "moved" reached from the second step on, the joint margin falling by 0.1 rad a step."""

    def _progress(self):
        return {SUBGOALS_REACHED: {"moved": self.t >= 2}, MIN_JOINT_MARGIN: 1.0 - 0.1 * self.t}

    def reset(self, *, seed=None, options=None):
        obs, info = super().reset(seed=seed, options=options)
        return obs, {**info, PROGRESS_INFO_KEY: self._progress()}

    def step(self, action):
        out = super().step(action)
        return *out[:4], {**out[4], PROGRESS_INFO_KEY: self._progress()}


def test_an_episode_record_holds_its_last_progress_and_the_summary_counts_it():
    records = []
    for length in (1, 3):
        env = LatencyHoldWrapper(ProgressEnv(length))
        env.reset(seed=length)
        env.pending_hold = 1 if length == 3 else None  # a held step is a control step too
        for _ in range(length):
            if env.step(_action(0.0).numpy())[3]:
                break
        records += env.pop_episode_records()
    assert [r[SUBGOALS_REACHED] for r in records] == [{"moved": False}, {"moved": True}]
    assert [r[MIN_JOINT_MARGIN] for r in records] == pytest.approx([0.9, 0.7])
    summary = summarize(records)
    assert summary["pc_subgoals"] == {"moved": 50.0}
    assert summary["pc_near_joint_limit"] == 0.0
    assert summary["mean_min_joint_margin_rad"] == pytest.approx(0.8)
    records[1][MIN_JOINT_MARGIN] = 0.05  # within robosuite's 0.1 rad tolerance
    records[1]["success"] = True
    summary = summarize(records)
    assert summary["pc_near_joint_limit"] == 50.0 and summary["pc_near_joint_limit_failed"] == 0.0
    # the records of an env without sub-goals (no EpisodeProgress) give success and smoothness only
    bare = [{k: v for k, v in r.items() if k not in (SUBGOALS_REACHED, MIN_JOINT_MARGIN)} for r in records]
    assert "pc_subgoals" not in summarize(bare) and summarize(bare)["pc_success"] == 50.0


def test_the_latency_envs_wrap_progress_only_where_the_env_reports_it():
    from lerobot_actionflow.envs.progress import EpisodeProgress
    from lerobot_actionflow.evaluation.latency_hold import _make_wrapped

    bare = _make_wrapped("CartPole-v1", True, {})  # a Gymnasium env with no sub-goals
    assert isinstance(bare, LatencyHoldWrapper) and not isinstance(bare.env, EpisodeProgress)
    bare.close()
