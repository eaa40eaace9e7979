"""How far an episode got: the task's sub-goals reached, and how close the arm came to a joint limit.

A failed episode says only that it failed. :class:`EpisodeProgress` records where it stopped:
after ``reset`` and after every ``step`` it adds ``info[PROGRESS_INFO_KEY]``, a dict of

- ``"subgoals_reached"``: ``{name: bool}``, the task's sub-goals (:attr:`TaskSpec.subgoals`, in
  task order), each True once it has held at any step of the episode so far. A sub-goal that
  held and was lost again (a dropped pod) stays reached: the record tells how far the episode
  got, not where it ended.
- ``"min_joint_margin_rad"``: the smallest distance of any arm joint to its range limit over the
  episode so far, in radians (:meth:`PoseTokenEnv.joint_limit_margin`).

The wrapper reads the simulator only; it changes no observation, reward or termination.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

#: The ``info`` key of the episode's progress so far.
PROGRESS_INFO_KEY = "episode_progress"
#: A joint closer than this to its limit counts as at the limit: the tolerance of robosuite's own
#: ``Robot.check_q_limits``, in radians.
NEAR_JOINT_LIMIT_RAD = 0.1


class EpisodeProgress(gym.Wrapper):
    """Adds ``info[PROGRESS_INFO_KEY]`` (the module docstring) to every ``reset`` and ``step``."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self._reached: dict[str, bool] = {}
        self._min_margin = float("inf")

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._reached, self._min_margin = {}, float("inf")
        return obs, self._with_progress(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, self._with_progress(info)

    def _with_progress(self, info: dict[str, Any]) -> dict[str, Any]:
        env = self.env.unwrapped
        for name, held in env.subgoals().items():
            self._reached[name] = self._reached.get(name, False) or held
        self._min_margin = min(self._min_margin, env.joint_limit_margin())
        progress = {"subgoals_reached": dict(self._reached), "min_joint_margin_rad": self._min_margin}
        return {**info, PROGRESS_INFO_KEY: progress}
