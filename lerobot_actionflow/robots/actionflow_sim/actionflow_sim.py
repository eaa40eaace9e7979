"""The simulated robot ``actionflow_sim``: a pose-token task running in real time.

A background thread (:class:`~lerobot_actionflow.robots.realtime.FixedRateLoop`) steps the
task's Gymnasium env once per control period (``1 / (CONTROL_FREQ * real_time_factor)`` s of
wall clock) whether or not the policy has answered. Each step applies the last commanded action,
an absolute EEF target ``[x, y, z, rot6d, gripper]`` in the world frame (held: a target that no
new action replaced is applied again); before the first action the target is the EEF pose at
reset with the gripper open. :meth:`get_observation` returns the state after the latest step
(named floats, :mod:`lerobot_actionflow.robots.layout`, and camera images), :meth:`send_action`
validates an action and makes it the target. The env lives on the stepping thread alone (it is
built, stepped, rendered and closed there), so observations are snapshots published under a
lock.

An episode ends at the task's success or after ``episode_length`` steps; its outcome is logged,
kept in :attr:`ActionFlowSim.episodes`, optionally appended to ``results_path``, and the next
episode starts from ``reset(seed + k)``. ``lerobot-rollout`` has no hook through which a robot
reports success or ends an episode (its base strategy runs until ``--duration`` or a shutdown
signal), so after the last episode the robot either raises SIGINT in its own process, which
``lerobot-rollout`` handles as a graceful stop (``on_done="stop"``), or freezes the simulation
(``"hold"``). The rollout does not reset the policy between the robot's episodes: with
``num_episodes > 1`` the first actions of an episode may come from the previous episode's chunk.
"""

from __future__ import annotations

import json
import logging
import signal
import threading
import time
from dataclasses import asdict, dataclass
from functools import cached_property
from typing import Any

import gymnasium as gym
import numpy as np
from lerobot.robots.robot import Robot
from lerobot.utils.errors import DeviceAlreadyConnectedError, DeviceNotConnectedError

from lerobot_actionflow.envs.tasks import CONTROL_FREQ, get_task
from lerobot_actionflow.robots.actionflow_sim.config_actionflow_sim import ActionFlowSimConfig
from lerobot_actionflow.robots.layout import (
    action_from_dict,
    action_names,
    flatten_observation,
    observation_names,
)
from lerobot_actionflow.robots.realtime import FixedRateLoop
from lerobot_actionflow.schema import ACTION_DIM, ACTION_GRIPPER_INDEX, ENV_AGENT_POS, ENV_PIXELS, POSE9_DIM

logger = logging.getLogger(__name__)

#: The gripper command before the first action: open.
GRIPPER_OPEN = -1.0


@dataclass(frozen=True)
class EpisodeResult:
    """The outcome of one simulated episode.

    Attributes:
        index, seed: the episode's number (from 0) and reset seed.
        success: whether the task succeeded before the time limit.
        steps: control steps simulated; ``sim_time_s = steps / CONTROL_FREQ``.
        wall_time_s: wall-clock time from the episode's first step to its end.
        actions_received: actions accepted by :meth:`ActionFlowSim.send_action`.
        actions_replaced: actions replaced by a newer one before any step applied them.
        steps_held: steps that applied a target already applied at the previous step (no new
            action had arrived): the policy was late.
        late_ticks: steps that started more than one period late (the simulator could not
            keep real time).
    """

    index: int
    seed: int
    success: bool
    steps: int
    sim_time_s: float
    wall_time_s: float
    actions_received: int
    actions_replaced: int
    steps_held: int
    late_ticks: int


class ActionFlowSim(Robot):
    """A pose-token task as a LeRobot robot (see the module docstring)."""

    config_class = ActionFlowSimConfig
    name = "actionflow_sim"

    def __init__(self, config: ActionFlowSimConfig):
        super().__init__(config)
        self.config = config
        self.spec = get_task(config.task)
        self._obs_names = observation_names(self.spec)
        self._image_shape = (config.camera_height, config.camera_width, 3)
        #: Camera name -> image shape (sim renders, not LeRobot camera devices).
        self.cameras: dict[str, tuple[int, int, int]] = {c: self._image_shape for c in config.camera_list}
        self.episodes: list[EpisodeResult] = []
        #: Set once the last episode has ended.
        self.done = threading.Event()
        self._lock = threading.Lock()
        self._loop: FixedRateLoop | None = None
        self._env: gym.Env | None = None
        self._latest: dict[str, Any] | None = None
        self._target = np.zeros(ACTION_DIM)
        self._fresh = False  # a target no step has applied yet
        self._running = False  # the clock runs (first action arrived, or not waiting for one)
        self._reset_counters()

    # ------------------------------------------------------------------ features
    @cached_property
    def observation_features(self) -> dict[str, type | tuple]:
        feats: dict[str, type | tuple] = dict.fromkeys(self._obs_names, float)
        feats.update(self.cameras)
        return feats

    @cached_property
    def action_features(self) -> dict[str, type]:
        return dict.fromkeys(action_names(), float)

    # ------------------------------------------------------------------ connection
    @property
    def is_connected(self) -> bool:
        return self._loop is not None and self._loop.running

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        """Nothing to calibrate in simulation."""

    def configure(self) -> None:
        """Nothing to configure in simulation."""

    def connect(self, calibrate: bool = True) -> None:
        """Build the env and reset it (on the stepping thread), then start the clock (at once,
        or at the first action with ``wait_for_first_action``)."""
        if self._loop is not None:
            raise DeviceAlreadyConnectedError(f"{self} is already connected")
        period = 1.0 / (CONTROL_FREQ * self.config.real_time_factor)
        self._loop = FixedRateLoop(
            self._tick, period, name=f"{self.name}-{self.spec.name}", setup=self._build, teardown=self._close
        )
        try:
            self._loop.start()
        except BaseException:
            self._loop = None
            raise
        logger.info(
            "%s connected: task %s, %d Hz simulated at x%g real time, %d episode(s) of <= %d steps",
            self.name, self.spec.name, CONTROL_FREQ, self.config.real_time_factor,
            self.config.num_episodes, self.config.episode_length,
        )  # fmt: skip

    def disconnect(self) -> None:
        if self._loop is None:
            raise DeviceNotConnectedError(f"{self} is not connected")
        loop, self._loop = self._loop, None
        loop.stop()
        ok = sum(e.success for e in self.episodes)
        logger.info("%s disconnected: %d/%d episode(s) succeeded", self.name, ok, len(self.episodes))

    # ------------------------------------------------------------------ I/O
    def get_observation(self) -> dict[str, Any]:
        """The latest simulated state: named floats (:mod:`~lerobot_actionflow.robots.layout`)
        and ``uint8 (H, W, 3)`` camera images."""
        self._check_alive()
        with self._lock:
            return dict(self._latest)

    def send_action(self, action: dict[str, Any]) -> dict[str, float]:
        """Make ``action`` (the named absolute EEF target, see :attr:`action_features`) the
        target that the following steps apply; returns it as sent.

        Raises:
            ValueError: a missing or unknown key, a non-finite value or a degenerate rotation.
        """
        self._check_alive()
        target = action_from_dict(action)
        self._env.unwrapped.to_robosuite_action(target)  # the env's own checks (rotation), raises early
        with self._lock:
            self._counters["actions_received"] += 1
            self._counters["actions_replaced"] += self._fresh
            self._target, self._fresh = target, True
            if not self._running:
                self._running = True
                self._episode_start = time.perf_counter()
        return dict(zip(action_names(), target.tolist(), strict=True))

    @property
    def sim_steps(self) -> int:
        """Control steps simulated in the current episode."""
        with self._lock:
            return self._steps

    # ------------------------------------------------------------------ stepping thread
    def _check_alive(self) -> None:
        if self._loop is None:
            raise DeviceNotConnectedError(f"{self} is not connected")
        if self._loop.error is not None:
            err = self._loop.error
            raise RuntimeError(f"{self.name}: the simulation stopped: {err!r}") from err

    def _build(self) -> None:
        cfg = self.config
        self._env = gym.make(
            self.spec.gym_id,
            max_episode_steps=cfg.episode_length,
            disable_env_checker=True,
            cameras=tuple(cfg.camera_list),
            image_height=cfg.camera_height,
            image_width=cfg.camera_width,
            render_mode=None,
            terminate_on_success=True,
        )
        try:
            self._reset_episode()
        except BaseException:
            self._close()
            raise
        self._running = not cfg.wait_for_first_action

    def _close(self) -> None:
        if self._env is not None:
            self._env.close()
            self._env = None

    def _reset_counters(self) -> None:
        self._steps = 0
        self._episode_start = time.perf_counter()
        self._late0 = self._loop.late_ticks if self._loop is not None else 0
        self._counters = {"actions_received": 0, "actions_replaced": 0, "steps_held": 0}

    def _reset_episode(self) -> None:
        """Reset the env for episode ``len(episodes)``; the target becomes the EEF pose, open."""
        obs, _ = self._env.reset(seed=self.config.seed + len(self.episodes))
        target = np.empty(ACTION_DIM)
        target[:POSE9_DIM] = obs[ENV_AGENT_POS][:POSE9_DIM]
        target[ACTION_GRIPPER_INDEX] = GRIPPER_OPEN
        with self._lock:
            self._target, self._fresh = target, False
            self._publish(obs)
            self._reset_counters()

    def _publish(self, obs: dict[str, Any]) -> None:
        latest: dict[str, Any] = flatten_observation(obs, self._obs_names)
        latest.update(obs.get(ENV_PIXELS, {}))
        self._latest = latest

    def _tick(self) -> None:
        with self._lock:
            if not self._running or self.done.is_set():
                return
            target, fresh = self._target, self._fresh
            self._fresh = False
        obs, _, terminated, truncated, info = self._env.step(target)
        with self._lock:
            self._publish(obs)
            self._steps += 1
            self._counters["steps_held"] += not fresh
        if terminated or truncated:
            self._end_episode(bool(info["is_success"]))

    def _end_episode(self, success: bool) -> None:
        with self._lock:
            result = EpisodeResult(
                index=len(self.episodes),
                seed=self.config.seed + len(self.episodes),
                success=success,
                steps=self._steps,
                sim_time_s=self._steps / CONTROL_FREQ,
                wall_time_s=time.perf_counter() - self._episode_start,
                late_ticks=self._loop.late_ticks - self._late0 if self._loop is not None else 0,
                **self._counters,
            )
            self.episodes.append(result)
        logger.info("%s %s episode %s", self.name, self.spec.name, asdict(result))
        if result.actions_replaced > 0.2 * max(result.actions_received, 1):
            logger.warning(
                "%s: %d of %d actions were replaced before a step applied them: the rollout runs "
                "faster than the control rate; pass --fps=%d",
                self.name, result.actions_replaced, result.actions_received, CONTROL_FREQ,
            )  # fmt: skip
        if self.config.results_path:
            with open(self.config.results_path, "a") as f:
                f.write(json.dumps({"task": self.spec.name, **asdict(result)}) + "\n")
        if len(self.episodes) < self.config.num_episodes:
            self._reset_episode()
            return
        self.done.set()
        if self.config.on_done == "stop":
            logger.info("%s: last episode done, asking the rollout to stop (SIGINT)", self.name)
            signal.raise_signal(signal.SIGINT)
