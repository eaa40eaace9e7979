"""The task registry: what a pose-token task is, and the table of all of them.

A :class:`TaskSpec` says which robosuite environment to build (a class given as an import path,
so that reading the registry never imports robosuite), which entities become pose tokens and in
which order, how long an episode lasts, what success means, and where the end-effector may be
sent. Row 0 of ``poses`` is always the end-effector; ``entities`` lists the rows after it.

Importing this module is cheap; the robosuite classes are imported by
:func:`TaskSpec.load_env_class` when an env is built.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

#: Control rate of every task (robosuite's default ``control_freq``), in Hz.
CONTROL_FREQ = 20


@dataclass(frozen=True)
class Entity:
    """One pose token after the end-effector.

    Exactly one of these is set; the token is the world pose of:

    - ``body``: a MuJoCo body (``xpos``, ``xquat``);
    - ``site`` / ``geom``: a MuJoCo site or geom (a point of interest on a body, e.g. the
      corner of a hook), as robosuite's own observations of some tasks use;
    - ``pose_fn``: ``"module:function"``, called with the robosuite env, returning
      ``(pos (3,), quat_wxyz (4,))``, for tokens that are no MuJoCo element (a goal region).
    """

    name: str
    body: str | None = None
    site: str | None = None
    geom: str | None = None
    pose_fn: str | None = None
    doc: str = ""

    def __post_init__(self):
        if sum(x is not None for x in (self.body, self.site, self.geom, self.pose_fn)) != 1:
            raise ValueError(f"entity {self.name!r}: set exactly one of body, site, geom and pose_fn")

    @property
    def kind(self) -> str:
        """``"body"``, ``"site"``, ``"geom"`` or ``"pose_fn"``."""
        return next(k for k in ("body", "site", "geom", "pose_fn") if getattr(self, k) is not None)

    def resolve_pose_fn(self) -> Callable[[Any], tuple[Any, Any]]:
        return _import(str(self.pose_fn))


@dataclass(frozen=True)
class TaskSpec:
    """Everything the pose-token env needs to know about one task.

    Attributes:
        name: the task name, also the gym id ``lerobot_actionflow/<name>-v0``.
        env_class: ``"module:Class"`` of the robosuite environment.
        env_kwargs: extra keyword arguments for that class (e.g. ``single_object_mode``).
        entities: the object tokens, rows 1.. of ``poses``, in this order.
        episode_length: steps before truncation (at ``CONTROL_FREQ`` Hz).
        description: the language instruction (``task_description``).
        success: a sentence stating the success criterion. The check itself is the robosuite
            env's ``_check_success()``.
        workspace_low, workspace_high: world-frame box the position part of an action is
            clipped to.
        fixtures: bodies without joints that belong to the task layout (pegs, stands) and move
            with a scene transform.
        pivot_xy: world xy point a scene transform rotates about (the placement centre).
        scene_transform: whether the task supports a scene transform (see
            :mod:`lerobot_actionflow.envs.scene_transform`); ``False`` where fixed parts of the
            arena (e.g. bins) define the goal.
        variant: placement-distribution variant (``"D0"``, ``"D1"``, ...) or ``""``.
        point_cloud_cameras: the depth cameras the point-cloud observation fuses by default
            (:mod:`lerobot_actionflow.envs.point_cloud`).
        point_cloud_removed: bodies whose subtrees are removed from point clouds, besides the
            robot: the arena's support surfaces (the table; Can's bins) and visual-only markers.
        subgoals: ``"module:function"``, called with the robosuite env, returning the task's
            sub-goals as ``{name: bool}`` in the order an expert reaches them (the last one is
            the success check or part of it); what an evaluation reads to say where failed
            episodes stop (:mod:`lerobot_actionflow.envs.progress`). ``None``: none defined.
    """

    name: str
    env_class: str
    entities: tuple[Entity, ...]
    episode_length: int
    description: str
    success: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    workspace_low: tuple[float, float, float] = (-0.35, -0.40, 0.80)
    workspace_high: tuple[float, float, float] = (0.35, 0.40, 1.35)
    fixtures: tuple[str, ...] = ()
    pivot_xy: tuple[float, float] = (0.0, 0.0)
    scene_transform: bool = True
    variant: str = ""
    point_cloud_cameras: tuple[str, ...] = ("agentview", "sideview")
    point_cloud_removed: tuple[str, ...] = ("table",)
    subgoals: str | None = None

    @property
    def num_tokens(self) -> int:
        """N: the end-effector plus the entities."""
        return 1 + len(self.entities)

    @property
    def gym_id(self) -> str:
        return f"lerobot_actionflow/{self.name}-v0"

    def load_env_class(self) -> type:
        return _import(self.env_class)

    def resolve_subgoals(self) -> Callable[[Any], dict[str, bool]] | None:
        """The :attr:`subgoals` function, or None."""
        return None if self.subgoals is None else _import(self.subgoals)


def _import(path: str) -> Any:
    """The attribute named by ``"module:attribute"``."""
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)


TASKS: dict[str, TaskSpec] = {}


def register_task(spec: TaskSpec) -> TaskSpec:
    """Add a task to :data:`TASKS`; a name may be registered once."""
    if spec.name in TASKS and TASKS[spec.name] != spec:
        raise ValueError(f"task {spec.name!r} is already registered with a different spec")
    TASKS[spec.name] = spec
    return spec


def get_task(name: str) -> TaskSpec:
    """The spec of ``name`` (``"Lift"``, also accepted as ``"Lift-v0"`` or a full gym id)."""
    key = name.removeprefix("lerobot_actionflow/").removesuffix("-v0")
    try:
        return TASKS[key]
    except KeyError:
        raise KeyError(f"unknown task {name!r}; known: {sorted(TASKS)}") from None
