"""Shared, session-scoped envs: building a robosuite env costs about a second, so each task's
env is made once and reused (every test resets it with its own seed)."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import gymnasium as gym
import pytest

import lerobot_actionflow.envs  # noqa: F401  (registers the gym ids)


@pytest.fixture(scope="session")
def env_cache():
    cache: dict[str, gym.Env] = {}
    yield cache
    for env in cache.values():
        env.close()


@pytest.fixture
def make_cached(env_cache):
    """``make_cached(gym_id)``: the session's env for that id (made on first use)."""

    def _get(gym_id: str) -> gym.Env:
        if gym_id not in env_cache:
            env_cache[gym_id] = gym.make(gym_id)
        return env_cache[gym_id]

    return _get
