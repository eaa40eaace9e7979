"""The MugHang expert hangs the mug on a moved hanger, and the task's check refuses the mug
while the gripper still holds it on the peg."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import lerobot_actionflow.envs  # noqa: F401  (gym ids)
from lerobot_actionflow.experts import make_expert


def test_expert_hangs_the_mug_and_a_held_threaded_mug_is_no_success():
    env = gym.make("lerobot_actionflow/MugHang_Moved-v0", render_mode=None)
    try:
        expert = make_expert("MugHang_Moved", env)
        rs = env.unwrapped.robosuite_env
        obs, _ = env.reset(seed=3)
        expert.reset(np.random.default_rng(3))
        held_on_peg, info = 0, {}
        for _ in range(env.unwrapped.spec_task.episode_length):
            action = expert.act(obs)
            obs, _, terminated, truncated, info = env.step(action)
            if action[-1] > 0 and rs.peg_through_handle():  # closed on the mug, threaded
                held_on_peg += 1
                assert not info["is_success"], f"success while held, in phase {expert.phase}"
            if terminated or truncated:
                break
        assert held_on_peg > 10  # the control was exercised
        assert info["is_success"], f"failed in phase {expert.phase}"
        assert expert.phase in ("release", "leave", "done")
    finally:
        env.close()
