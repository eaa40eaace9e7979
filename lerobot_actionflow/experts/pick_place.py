"""Base class of the top-down pick-and-place experts, and the random-draw contract.

Random draws. Every random choice of an episode comes from the one ``rng`` given to
:meth:`PickPlaceExpert.plan` (``np.random.default_rng(seed)`` in
:func:`~lerobot_actionflow.experts.rollout.run_episode`), each choice the next draw from it, so
the order of the draws is part of every demonstration: reordering, adding or dropping one
changes every demonstration after it (and needs a new expert ``version``). The order is:

1. the episode's ``tempo`` (:meth:`PickPlaceExpert.plan`);
2. the task's draws, in the order of the fields of the task's ``*Draws`` dataclass (its
   ``draw`` classmethod, in the task's module), where a skill's draws
   (:class:`~lerobot_actionflow.experts.skills.PickDraws`,
   :class:`~lerobot_actionflow.experts.skills.PlaceDraws`,
   :class:`~lerobot_actionflow.experts.relocate.RelocateDraws`) are drawn in the order of that
   dataclass's fields in turn.

A plan draws everything first, then builds its waypoints without touching ``rng``.
``tests/experts/test_draw_order.py`` pins every expert's sequence of draws.
"""

from __future__ import annotations

import numpy as np

from lerobot_actionflow.experts import frames as fr
from lerobot_actionflow.experts.base import Waypoint, WaypointExpert
from lerobot_actionflow.experts.pose import token_pose
from lerobot_actionflow.experts.skills import (
    Grasp,
    Pick,
    PickDraws,
    PickParams,
    Place,
    PlaceDraws,
    PlaceParams,
)
from lerobot_actionflow.schema import ENV_POSES


class PickPlaceExpert(WaypointExpert):
    """Base of the top-down experts: the episode's ``tempo`` (the first draw of every plan),
    the arm's home heading, the robot base, and the skills' waypoints."""

    #: Speed factor of the episode (every drawn speed is multiplied by it).
    tempo: float = 1.0
    _home: float | None = None

    def plan(self, rng: np.random.Generator) -> list[Waypoint]:
        self.tempo = float(rng.uniform(0.8, 1.2))
        self._home = None
        return self.task_plan(rng)

    def task_plan(self, rng: np.random.Generator) -> list[Waypoint]:
        """The task's draws (its ``*Draws.draw``), then its waypoints."""
        raise NotImplementedError

    def entity_row(self, name: str) -> int:
        """Row of entity ``name`` in ``obs["poses"]`` (row 0 is the EEF)."""
        return 1 + [e.name for e in self.env.spec_task.entities].index(name)

    @staticmethod
    def eef_heading(obs: dict) -> float:
        """Heading ``psi`` of the measured EEF orientation (:func:`.frames.heading`)."""
        return fr.heading(token_pose(obs, 0).r)

    def home_heading(self, obs: dict) -> float:
        """The arm's home heading: the EEF heading when a pick first asked for it (the
        episode's first observation: every plan begins with a pick)."""
        if self._home is None:
            self._home = self.eef_heading(obs)
        return self._home

    def robot_base_xy(self) -> np.ndarray:
        return np.asarray(self.env.robosuite_env.robots[0].base_pos[:2], dtype=np.float64)

    def reach(self, p: np.ndarray) -> float:
        """Horizontal distance (m) of world point ``p`` from the robot base."""
        return float(np.linalg.norm(np.asarray(p, dtype=np.float64)[:2] - self.robot_base_xy()))

    def object_xyz(self, obs: dict, row: int) -> np.ndarray:
        """World position ``(3,)`` of row ``row`` of ``obs["poses"]``."""
        return np.asarray(obs[ENV_POSES][row, :3], dtype=np.float64)

    def pick(self, grasp: Grasp, params: PickParams, draws: PickDraws, when=None) -> list[Waypoint]:
        return Pick(self, grasp, params, draws).waypoints(when)

    def place(self, grasp: Grasp, goal, params: PlaceParams, draws: PlaceDraws, rot=None, when=None):
        return Place(grasp, goal, params, draws, rot).waypoints(when)
