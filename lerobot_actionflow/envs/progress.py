"""How far an episode got: the task's sub-goals reached, and how close the arm came to a joint limit.

A failed episode says only that it failed. :class:`EpisodeProgress` records where it stopped:
after ``reset`` and after every ``step`` it adds ``info[PROGRESS_INFO_KEY]``, a dict of

- :data:`SUBGOALS_REACHED`: ``{name: bool}``, the task's sub-goals (:attr:`TaskSpec.subgoals`,
  in task order), reached in order: sub-goal ``i`` becomes True at the first control step at
  which it holds and sub-goals ``0 .. i-1`` are already reached (a Coffee lid knocked shut before
  the pod is in its holder does not count). Once reached it stays reached, even if it is lost
  again (a dropped pod): the record tells how far the episode got, not where it ended.
- :data:`MIN_JOINT_MARGIN`: the smallest distance of any arm joint to its range limit at the
  control steps of the episode so far, in radians (:meth:`PoseTokenEnv.joint_limit_margin`;
  the physics substeps between two control steps are not sampled).

The wrapper reads the simulator only; it changes no observation, reward or termination. It
needs an env whose ``unwrapped`` has ``subgoals()`` and ``joint_limit_margin()``
(:class:`~lerobot_actionflow.envs.pose_env.PoseTokenEnv`); :func:`reports_progress` tells.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

#: The ``info`` key of the episode's progress so far.
PROGRESS_INFO_KEY = "episode_progress"
#: The progress record's keys: the sub-goals reached, in task order, and the smallest joint margin.
SUBGOALS_REACHED = "subgoals_reached"
MIN_JOINT_MARGIN = "min_joint_margin_rad"
#: A joint closer than this to its limit counts as at the limit: the tolerance of robosuite's own
#: ``Robot.check_q_limits``, in radians.
NEAR_JOINT_LIMIT_RAD = 0.1


def reports_progress(env: gym.Env) -> bool:
    """Whether :class:`EpisodeProgress` can wrap ``env``: its unwrapped env has sub-goals and a
    joint-limit margin."""
    return all(callable(getattr(env.unwrapped, m, None)) for m in ("subgoals", "joint_limit_margin"))


class EpisodeProgress(gym.Wrapper):
    """Adds ``info[PROGRESS_INFO_KEY]`` (the module docstring) to every ``reset`` and ``step``."""

    def __init__(self, env: gym.Env):
        if not reports_progress(env):
            raise TypeError(
                f"EpisodeProgress needs an env with subgoals() and joint_limit_margin() "
                f"(a PoseTokenEnv), got {type(env.unwrapped).__name__}"
            )
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
        earlier_reached = True
        for name, held in env.subgoals().items():
            self._reached[name] = self._reached.get(name, False) or (held and earlier_reached)
            earlier_reached = self._reached[name]
        self._min_margin = min(self._min_margin, env.joint_limit_margin())
        progress = {SUBGOALS_REACHED: dict(self._reached), MIN_JOINT_MARGIN: self._min_margin}
        return {**info, PROGRESS_INFO_KEY: progress}
