"""A Gymnasium wrapper in which time passes while the policy infers.

:class:`LatencyHoldWrapper` wraps one pose-token env (absolute EEF actions ``[x, y, z, rot6d,
gripper]``). Before the ``step(a)`` that applies the first action of a new chunk, whoever drives
the evaluation sets :attr:`LatencyHoldWrapper.pending_hold` (through the vector env's
``set_attr``), and the env first advances one control step per held action:

* an integer ``k``: ``k`` steps holding the previous commanded target (at the start of an
  episode, the current EEF pose with the gripper open, i.e. the arm stays where it is);
* an array ``(k, ACTION_DIM)``: ``k`` steps applying those targets (simulated real-time chunking:
  the robot keeps executing the previous chunk while the next one is inferred).

An episode that ends during the held steps ends there (the new action is never applied). One
``step`` then covers ``k + 1`` control steps; its reward is their sum and its info the last one's.

Every commanded target of an episode is recorded; at the episode's end its smoothness figures
(:mod:`lerobot_actionflow.evaluation.smoothness`) and its progress (sub-goals reached, closest
approach to a joint limit: :mod:`lerobot_actionflow.envs.progress`, whose wrapper
:func:`make_latency_envs` puts inside this one) join :attr:`episode_records`, read and cleared
with :meth:`pop_episode_records`. After the end of an episode the env is frozen like LeRobot's
``FreezeAfterEpisodeEnd``: Gymnasium's argument-less autoreset and further steps replay the
terminal transition, so that only episodes started by a rollout (``reset`` with LeRobot's
``NEW_ROLLOUT_OPTION``, or with a seed) are simulated and recorded.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from lerobot.envs.utils import NEW_ROLLOUT_OPTION

from lerobot_actionflow.envs.progress import PROGRESS_INFO_KEY, EpisodeProgress, reports_progress
from lerobot_actionflow.evaluation.smoothness import smoothness_figures
from lerobot_actionflow.schema import ACTION_DIM, ACTION_GRIPPER_INDEX, ENV_AGENT_POS, POSE9_DIM

#: The gripper command of an open gripper (the state of every task at reset).
GRIPPER_OPEN = -1.0


def idle_target(observation: dict[str, Any]) -> np.ndarray:
    """The target that keeps the arm still: the EEF pose9 of ``observation[ENV_AGENT_POS]`` and an
    open gripper ``(ACTION_DIM,)``."""
    target = np.empty(ACTION_DIM)
    target[:POSE9_DIM] = np.asarray(observation[ENV_AGENT_POS], dtype=np.float64)[:POSE9_DIM]
    target[ACTION_GRIPPER_INDEX] = GRIPPER_OPEN
    return target


class LatencyHoldWrapper(gym.Wrapper):
    """Holds (or plays) targets for the inference delay before a chunk's first action.

    Attributes:
        pending_hold: ``None``, an int ``k >= 0`` or targets ``(k, ACTION_DIM)``, consumed by the
            next ``step``.
        episode_records: one dict per finished episode: ``seed``, ``success``, ``control_steps``,
            ``held_steps``, ``chunks``, the figures of
            :func:`~lerobot_actionflow.evaluation.smoothness.smoothness_figures` and, when the
            wrapped env reports it, the episode's progress (the record of
            :class:`~lerobot_actionflow.envs.progress.EpisodeProgress`).
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.pending_hold: int | np.ndarray | None = None
        self.episode_records: list[dict[str, Any]] = []
        self._frozen: tuple | None = None
        self._targets: list[np.ndarray] = []
        self._last_target: np.ndarray | None = None
        self._seed: int | None = None
        self._held = 0
        self._chunks = 0
        self._success = False
        self._progress: dict[str, Any] = {}
        self._recording = False

    # -- gym API ----------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        genuine = seed is not None or bool((options or {}).get(NEW_ROLLOUT_OPTION))
        if self._frozen is not None and not genuine:
            obs, _, _, _, info = self._frozen  # Gymnasium's autoreset of a finished episode
            return obs, info
        if self._recording:  # an episode left unfinished (its rollout stopped early)
            self._finish_episode()
        obs, info = self.env.reset(seed=seed, options=options)
        self._frozen = None
        self.pending_hold = None
        self._targets, self._last_target = [], idle_target(obs)
        self._seed, self._held, self._chunks, self._success = seed, 0, 0, bool(info.get("is_success"))
        self._progress = info.get(PROGRESS_INFO_KEY, {})
        self._recording = True
        return obs, info

    def step(self, action):
        if self._frozen is not None:
            return self._frozen
        holds, self.pending_hold = self._hold_targets(self.pending_hold), None
        if holds is not None:
            self._chunks += 1
        reward = 0.0
        for target in [] if holds is None else holds:
            obs, r, terminated, truncated, info = self._apply(target)
            reward += r
            self._held += 1
            if terminated or truncated:
                return self._end(obs, reward, terminated, truncated, info)
        obs, r, terminated, truncated, info = self._apply(np.asarray(action, dtype=np.float64))
        reward += r
        if terminated or truncated:
            return self._end(obs, reward, terminated, truncated, info)
        return obs, reward, terminated, truncated, info

    # -- records ----------------------------------------------------------------------------------
    def pop_episode_records(self) -> list[dict[str, Any]]:
        """The finished episodes' records since the last call (and forget them)."""
        records, self.episode_records = self.episode_records, []
        return records

    # -- internals --------------------------------------------------------------------------------
    def _hold_targets(self, hold: int | np.ndarray | None) -> np.ndarray | None:
        if hold is None:
            return None
        if isinstance(hold, (int, np.integer)) and not isinstance(hold, bool):
            if hold < 0:
                raise ValueError(f"pending_hold must be >= 0 steps, got {hold}")
            return np.repeat(self._last_target[None], int(hold), axis=0)
        held = np.asarray(hold, dtype=np.float64)
        if held.ndim != 2 or held.shape[1] != ACTION_DIM:
            raise ValueError(
                f"pending_hold must be an int or targets (k, {ACTION_DIM}), got shape {held.shape}"
            )
        return held

    def _apply(self, target: np.ndarray):
        out = self.env.step(target)
        self._targets.append(target)
        self._last_target = target
        self._success = self._success or bool(out[4].get("is_success"))
        self._progress = out[4].get(PROGRESS_INFO_KEY, self._progress)
        return out

    def _end(self, obs, reward, terminated, truncated, info):
        self._frozen = (obs, 0.0, terminated, truncated, info)
        self._finish_episode()
        return obs, reward, terminated, truncated, info

    def _finish_episode(self) -> None:
        targets = np.stack(self._targets) if self._targets else np.empty((0, ACTION_DIM))
        self.episode_records.append(
            {
                "seed": self._seed,
                "success": self._success,
                "control_steps": len(targets),
                "held_steps": self._held,
                "chunks": self._chunks,
                **smoothness_figures(targets),
                **self._progress,
            }
        )
        self._recording = False


def _make_wrapped(gym_id: str, disable_env_checker: bool, gym_kwargs: dict) -> gym.Env:
    env = gym.make(gym_id, disable_env_checker=disable_env_checker, **gym_kwargs)
    return LatencyHoldWrapper(EpisodeProgress(env) if reports_progress(env) else env)


def make_latency_envs(env_cfg, n_envs: int = 1, use_async_envs: bool = False) -> gym.vector.VectorEnv:
    """A vector env of ``n_envs`` :class:`LatencyHoldWrapper` envs of a single-task LeRobot env
    config (e.g. ``actionflow``), built as LeRobot's ``EnvConfig.create_envs`` builds it
    (``gym.make(cfg.gym_id, **cfg.gym_kwargs)``, same-step autoreset, forkserver workers)."""
    from functools import partial

    from gymnasium.vector import AutoresetMode

    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    make = partial(_make_wrapped, env_cfg.gym_id, env_cfg.disable_env_checker, env_cfg.gym_kwargs)
    if use_async_envs and n_envs > 1:
        return gym.vector.AsyncVectorEnv(
            [make] * n_envs, autoreset_mode=AutoresetMode.SAME_STEP, context="forkserver"
        )
    return gym.vector.SyncVectorEnv([make] * n_envs, autoreset_mode=AutoresetMode.SAME_STEP)
