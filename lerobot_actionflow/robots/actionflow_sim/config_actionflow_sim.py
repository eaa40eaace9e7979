"""LeRobot robot type ``actionflow_sim``: ``--robot.type=actionflow_sim --robot.task=Lift``.

Importing this module registers the type (``RobotConfig.register_subclass``); it imports neither
robosuite nor the robot itself. LeRobot builds the robot from this config by name
(``make_device_from_device_class``: ``ActionFlowSimConfig`` -> ``ActionFlowSim``, found in the
sibling module :mod:`.actionflow_sim`).
"""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.robots.config import RobotConfig

import lerobot_actionflow.envs  # noqa: F401  (fills the task table)
from lerobot_actionflow.envs.tasks import CONTROL_FREQ, get_task

#: What the robot does once its last episode has ended.
ON_DONE = ("stop", "hold")


@RobotConfig.register_subclass("actionflow_sim")
@dataclass(kw_only=True)
class ActionFlowSimConfig(RobotConfig):
    """A pose-token task simulated in real time (see :mod:`.actionflow_sim`).

    Attributes:
        task: task name (``Lift``, ``Can``, ``Square``, ``StackThree_D0``, ...).
        seed: seed of the first episode; episode ``k`` is reset with ``seed + k``.
        num_episodes: episodes to run; each ends at the task's success or its time limit.
        episode_length: time limit in control steps; ``None`` for the task's own.
        cameras: comma-separated camera images to observe (``"wrist,agentview"``); empty for none.
        camera_height, camera_width: their size in pixels.
        real_time_factor: simulated seconds per wall-clock second (1 is real time).
        wait_for_first_action: hold the simulation in its reset state until the first action
            arrives (the policy's first inference, loading and warm-up are then not charged
            to the first episode); later episodes start at once.
        on_done: after the last episode, ``"stop"`` asks the rollout to end (SIGINT to this
            process, which ``lerobot-rollout`` handles as a graceful shutdown), ``"hold"``
            freezes the simulation and keeps answering.
        results_path: a file to append one JSON line per finished episode to; ``None``: log only.
    """

    task: str = "Lift"
    seed: int = 0
    num_episodes: int = 1
    episode_length: int | None = None
    cameras: str = ""
    camera_height: int = 84
    camera_width: int = 84
    real_time_factor: float = 1.0
    wait_for_first_action: bool = True
    on_done: str = "stop"
    results_path: str | None = None

    def __post_init__(self):
        # RobotConfig.__post_init__ only checks LeRobot camera configs; these cameras are the
        # simulator's own renders, named by a string, and are validated here instead.
        spec = get_task(str(self.task))  # KeyError naming the known tasks
        self.task = spec.name
        if self.episode_length is None:
            self.episode_length = spec.episode_length
        for name in ("num_episodes", "episode_length", "camera_height", "camera_width"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"robot.{name} must be >= 1, got {getattr(self, name)}")
        if not self.real_time_factor > 0:
            raise ValueError(f"robot.real_time_factor must be > 0, got {self.real_time_factor}")
        if self.on_done not in ON_DONE:
            raise ValueError(f"robot.on_done must be one of {ON_DONE}, got {self.on_done!r}")
        if not isinstance(self.wait_for_first_action, bool):
            raise TypeError(f"robot.wait_for_first_action must be a bool, got {self.wait_for_first_action!r}")

    @property
    def camera_list(self) -> list[str]:
        return [c.strip() for c in self.cameras.split(",") if c.strip()]

    @property
    def control_freq(self) -> int:
        """The task's control rate in Hz (simulated time)."""
        return CONTROL_FREQ
