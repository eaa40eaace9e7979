"""How far an episode got: every task's sub-goals, the arm's joint-limit margin, and the
:class:`EpisodeProgress` wrapper that records both."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from env_success_states import construct_success

import lerobot_actionflow.envs as af_envs
from lerobot_actionflow.envs.progress import (
    MIN_JOINT_MARGIN,
    PROGRESS_INFO_KEY,
    SUBGOALS_REACHED,
    EpisodeProgress,
    reports_progress,
)
from lerobot_actionflow.experts import make_expert


def _is_grasp(name: str) -> bool:
    return name.endswith("_grasped")


@pytest.mark.parametrize("gym_id", list(af_envs.GYM_IDS))
def test_no_subgoal_holds_at_reset_and_every_placement_holds_in_a_success_state(make_cached, gym_id):
    env = make_cached(gym_id).unwrapped
    env.reset(seed=2)
    at_reset = env.subgoals()
    assert at_reset, f"{gym_id} defines no sub-goals"
    assert not any(at_reset.values()), at_reset
    construct_success(env)  # objects placed, far from the open gripper
    held = env.subgoals()
    assert list(held) == list(at_reset)  # the same names, in task order
    assert {n: v for n, v in held.items() if not _is_grasp(n)} == {n: True for n in held if not _is_grasp(n)}
    assert not any(v for n, v in held.items() if _is_grasp(n)), held


#: One variant of each task family: every family's sub-goal functions fire in a real episode.
ONE_PER_FAMILY = [
    "Lift", "Can", "Square", "ToolHang", "StackThree_D0", "Threading_D0", "ThreePieceAssembly_D0",
    "Coffee_D0", "MugHang_D0",
]  # fmt: skip


def test_one_per_family_covers_every_family():
    families = {gym_id.split("/")[1].removesuffix("-v0").split("_")[0] for gym_id in af_envs.GYM_IDS}
    assert {t.split("_")[0] for t in ONE_PER_FAMILY} == families


@pytest.mark.parametrize("task", ONE_PER_FAMILY)
def test_an_expert_episode_reaches_every_subgoal_in_task_order(task):
    env = EpisodeProgress(gym.make(f"lerobot_actionflow/{task}-v0", render_mode=None))
    try:
        expert = make_expert(task, env)
        obs, info = env.reset(seed=0)
        expert.reset(np.random.default_rng(0))
        assert not any(info[PROGRESS_INFO_KEY][SUBGOALS_REACHED].values())
        first: dict[str, int] = {}
        for step in range(env.unwrapped.spec_task.episode_length):
            obs, _, terminated, truncated, info = env.step(expert.act(obs))
            for name, reached in info[PROGRESS_INFO_KEY][SUBGOALS_REACHED].items():
                if reached:
                    first.setdefault(name, step)
            if terminated or truncated:
                break
        assert info["is_success"]
        names = list(env.unwrapped.subgoals())
        assert list(first) == names, first  # all reached, first reached in task order
        steps = [first[n] for n in names]
        assert steps == sorted(steps) and steps[0] < steps[-1], first
        assert np.isfinite(info[PROGRESS_INFO_KEY][MIN_JOINT_MARGIN])
    finally:
        env.close()


def test_joint_limit_margin_is_the_distance_of_the_closest_joint_to_its_limit(make_cached):
    env = make_cached("lerobot_actionflow/Lift-v0").unwrapped
    env.reset(seed=0)
    at_home = env.joint_limit_margin()
    assert 0.1 < at_home < np.pi
    adr, (low, _) = env._arm_qpos[3], env._arm_range[3]
    env._data.qpos[adr] = low + 0.02
    assert env.joint_limit_margin() == pytest.approx(0.02)
    env._data.qpos[adr] = low - 0.01  # past a soft limit: negative
    assert env.joint_limit_margin() == pytest.approx(-0.01)


class _ScriptedEnv(gym.Env):
    """Sub-goals and joint margins played from a script, one entry per reset/step."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,))
    action_space = gym.spaces.Box(-1.0, 1.0, (1,))

    def __init__(self, script: list[tuple[dict[str, bool], float]]):
        self.script, self.t = script, 0

    def subgoals(self):
        return self.script[self.t][0]

    def joint_limit_margin(self):
        return self.script[self.t][1]

    def reset(self, *, seed=None, options=None):
        self.t = 0
        return np.zeros(1, np.float32), {"is_success": False}

    def step(self, action):
        self.t += 1
        return np.zeros(1, np.float32), 0.0, False, False, {"is_success": False, "other": self.t}


def test_episode_progress_keeps_a_subgoal_once_reached_and_the_smallest_margin_until_reset():
    script = [
        ({"a": False, "b": False}, 0.5),
        ({"a": True, "b": False}, 0.3),
        ({"a": False, "b": False}, 0.4),  # "a" lost again: it stays reached
        ({"a": False, "b": True}, 0.6),
    ]
    env = EpisodeProgress(_ScriptedEnv(script))
    at_start = {SUBGOALS_REACHED: {"a": False, "b": False}, MIN_JOINT_MARGIN: 0.5}
    _, info = env.reset()
    assert info[PROGRESS_INFO_KEY] == at_start
    seen = [env.step(np.zeros(1))[4] for _ in range(3)]
    assert [s["other"] for s in seen] == [1, 2, 3]  # the wrapped env's info is kept
    assert [s[PROGRESS_INFO_KEY][SUBGOALS_REACHED] for s in seen] == [
        {"a": True, "b": False},
        {"a": True, "b": False},
        {"a": True, "b": True},
    ]
    assert [s[PROGRESS_INFO_KEY][MIN_JOINT_MARGIN] for s in seen] == [0.3, 0.3, 0.3]
    _, info = env.reset()  # a new episode forgets the last one
    assert info[PROGRESS_INFO_KEY] == at_start


def test_a_later_subgoal_counts_only_once_the_earlier_ones_are_reached():
    script = [
        ({"a": False, "b": False}, 0.5),
        ({"a": False, "b": True}, 0.5),  # "b" before "a" (a lid knocked shut with no pod): not reached
        ({"a": True, "b": False}, 0.5),
        ({"a": False, "b": False}, 0.5),
        ({"a": False, "b": True}, 0.5),  # "b" after "a" was reached, though "a" no longer holds
    ]
    env = EpisodeProgress(_ScriptedEnv(script))
    env.reset()
    seen = [env.step(np.zeros(1))[4][PROGRESS_INFO_KEY][SUBGOALS_REACHED] for _ in range(4)]
    assert seen == [
        {"a": False, "b": False},
        {"a": True, "b": False},
        {"a": True, "b": False},
        {"a": True, "b": True},
    ]


class _NoProgressEnv(_ScriptedEnv):
    subgoals = None


def test_episode_progress_refuses_an_env_without_subgoals_and_names_it():
    assert reports_progress(_ScriptedEnv([({}, 1.0)]))
    assert not reports_progress(_NoProgressEnv([({}, 1.0)]))
    with pytest.raises(TypeError, match=r"subgoals.*_NoProgressEnv"):
        EpisodeProgress(_NoProgressEnv([({}, 1.0)]))
