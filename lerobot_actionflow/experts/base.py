"""Scripted experts: the protocol and a waypoint state machine that drives the absolute OSC arm.

An expert is made for one env (:class:`PoseTokenEnv`, for geometry such as object sizes), then
for every episode ``reset(rng)`` draws its random choices (grasp heading among an object's
symmetric alternatives, waypoint offsets, speeds, pauses) and ``act(obs)`` returns the env's
action ``[pose9 (9), gripper]`` ``(10,)`` (:data:`lerobot_actionflow.schema.ACTION_KEY`: absolute
world EEF target ``[x, y, z, rot6d]``, gripper -1 open / +1 closed).

:class:`WaypointExpert` runs a list of :class:`Waypoint` s. Each waypoint is a target EEF pose,
computed from the observation (usually an offset in an object's frame, so the plan follows
where the objects really are), and a gripper command. A target that is not ``track`` ed is
computed once, as its phase begins; state that outlives a phase (a grasp recorded when the
fingers closed, a placement frozen when a carry began) lives in the expert's typed per-episode
objects (e.g. :class:`~lerobot_actionflow.experts.skills.Grasp`), which the targets read.

The commanded pose moves from the previous command towards the target at a bounded speed,
``|dp| <= v dt`` and ``|Log(r_cmd^T r_target)| <= w dt`` per step (geodesic step
``r <- r Exp(s Log(r^T r_t))``), so demonstrations are smooth and their speeds vary with ``v``,
``w``. A waypoint is reached when the command equals the target and the measured EEF is within
``tol`` of it; the expert then holds for ``hold`` steps (gripper timing and pauses) and goes on.
A waypoint that takes more than ``timeout`` steps is left anyway (the controller cannot always
reach a pose exactly, e.g. when pressing an object onto another); the task's success check
decides whether the episode is kept.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from lerobot_actionflow import rotations
from lerobot_actionflow.envs.tasks import CONTROL_FREQ
from lerobot_actionflow.experts import frames as fr
from lerobot_actionflow.experts.pose import Pose, token_pose


class Expert:
    """Protocol of a scripted expert (see the module docstring)."""

    #: Bumped whenever the behaviour changes; recorded in dataset metadata.
    version: str = "0"
    #: Task names this expert is registered for.
    tasks: tuple[str, ...] = ()

    def __init__(self, env):
        self.env = env

    def reset(self, rng: np.random.Generator) -> None:
        raise NotImplementedError

    def act(self, obs: dict[str, Any]) -> np.ndarray:
        raise NotImplementedError

    @property
    def done(self) -> bool:
        """Whether the plan is finished (the expert then holds its last command)."""
        return False


@dataclass
class Waypoint:
    """One phase of a plan.

    Attributes:
        name: for logs and tests.
        target: ``obs -> Pose``: the world EEF target.
        gripper: gripper command during the phase (-1 open, +1 closed).
        speed: max translation speed of the command (m/s).
        rot_speed: max rotation speed of the command (rad/s).
        tol: position tolerance (m) of the measured EEF for "reached".
        hold: steps to stay after reaching (gripper closing time, pauses).
        timeout: steps after which the phase is left even if not reached.
        track: recompute the target every step (else once, at phase entry).
        on_exit: ``obs -> None``, called when the phase ends.
        when: ``obs -> bool``, asked as the phase is reached (with the observation of
            the step that ended the previous one): False skips it (no step is spent), for plans
            with optional parts.
    """

    name: str
    target: Callable[[dict], Pose]
    gripper: float = -1.0
    speed: float = 0.25
    rot_speed: float = 1.5
    tol: float = 0.01
    hold: int = 0
    timeout: int = 200
    track: bool = False
    on_exit: Callable[[dict], None] | None = None
    when: Callable[[dict], bool] | None = None


@dataclass
class _State:
    """Progress through the plan: current waypoint, steps spent in it, steps held at it."""

    index: int = 0
    steps: int = 0
    held: int = 0
    target: Pose | None = None
    #: The last commanded EEF pose, and gripper command.
    cmd: Pose | None = None
    gripper: float = -1.0


class WaypointExpert(Expert):
    """Runs :meth:`plan` (a list of :class:`Waypoint`) with the bounded-speed command above."""

    #: Seconds per step: the tasks' control period.
    dt: float = 1.0 / CONTROL_FREQ

    def plan(self, rng: np.random.Generator) -> list[Waypoint]:
        """The waypoints of one episode; all its random choices are drawn here from ``rng``."""
        raise NotImplementedError

    def reset(self, rng: np.random.Generator) -> None:
        self.waypoints = self.plan(rng)
        self.state = _State()

    @property
    def done(self) -> bool:
        return self.state.index >= len(self.waypoints)

    @property
    def phase(self) -> str:
        return "done" if self.done else self.waypoints[self.state.index].name

    @staticmethod
    def eef(obs: dict) -> Pose:
        """The measured EEF pose (row 0 of ``poses``)."""
        return token_pose(obs, 0)

    def act(self, obs: dict[str, Any]) -> np.ndarray:
        s = self.state
        if s.cmd is None:
            s.cmd = self.eef(obs)
            s.gripper = -1.0
            self._skip_unwanted(obs)
        if self.done:
            return fr.action(s.cmd, s.gripper)
        wp = self.waypoints[s.index]
        if s.target is None or wp.track:
            s.target = wp.target(obs)
        s.cmd = self._step_towards(s.cmd, s.target, wp.speed, wp.rot_speed)
        s.gripper = wp.gripper
        action = fr.action(s.cmd, wp.gripper)
        p_eef = self.eef(obs).p
        at_target = np.allclose(s.cmd.p, s.target.p, atol=1e-9) and np.allclose(
            s.cmd.r, s.target.r, atol=1e-9
        )
        s.steps += 1
        if at_target and np.linalg.norm(p_eef - s.target.p) < wp.tol:
            s.held += 1
        if s.held > wp.hold or s.steps >= wp.timeout:
            if wp.on_exit is not None:
                wp.on_exit(obs)
            s.index, s.steps, s.held, s.target = s.index + 1, 0, 0, None
            self._skip_unwanted(obs)
        return action

    def _skip_unwanted(self, obs: dict[str, Any]) -> None:
        """Pass over the waypoints, from the current one on, whose ``when`` says no."""
        s = self.state
        while not self.done and (w := self.waypoints[s.index].when) is not None and not w(obs):
            s.index += 1

    def _step_towards(self, cmd: Pose, target: Pose, v: float, w: float) -> Pose:
        """One bounded step from ``cmd`` towards ``target``: at most ``v dt`` (m) along the
        straight line and ``w dt`` (rad) along the geodesic ``r Exp(s Log(r^T r_t))``."""
        d = target.p - cmd.p
        dist = float(np.linalg.norm(d))
        step = v * self.dt
        p = target.p.copy() if dist <= step else cmd.p + d * (step / dist)
        omega = rotations.matrix_to_axis_angle(cmd.r.T @ target.r)
        ang = float(np.linalg.norm(omega))
        rstep = w * self.dt
        r = target.r.copy() if ang <= rstep else cmd.r @ rotations.axis_angle_to_matrix(omega * (rstep / ang))
        return Pose(r, p)
