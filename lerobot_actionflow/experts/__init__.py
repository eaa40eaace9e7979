"""Scripted experts for the pose-token tasks, and the registry task name -> expert class.

``make_expert(task, env)`` builds the expert of a task for an env (``env.unwrapped`` of a
``gym.make("lerobot_actionflow/<Task>-v0")``); ``expert.reset(rng)`` per episode, then
``expert.act(obs) -> (10,)`` each step. Only experts whose measured success rate is reported
in ``benchmarks/RESULTS.md`` ("Scripted experts") are registered.
"""

from __future__ import annotations

from lerobot_actionflow.experts.base import Expert, Waypoint, WaypointExpert
from lerobot_actionflow.experts.can import CanExpert
from lerobot_actionflow.experts.coffee import CoffeeExpert
from lerobot_actionflow.experts.lift import LiftExpert
from lerobot_actionflow.experts.mug_hang import MugHangExpert
from lerobot_actionflow.experts.square import SquareExpert
from lerobot_actionflow.experts.stack_three import StackThreeExpert
from lerobot_actionflow.experts.threading import ThreadingExpert
from lerobot_actionflow.experts.three_piece_assembly import ThreePieceAssemblyExpert
from lerobot_actionflow.experts.tool_hang import ToolHangExpert

EXPERTS: dict[str, type[Expert]] = {}


def register_expert(cls: type[Expert]) -> type[Expert]:
    for task in cls.tasks:
        EXPERTS[task] = cls
    return cls


for _cls in (
    LiftExpert,
    StackThreeExpert,
    CanExpert,
    SquareExpert,
    ThreePieceAssemblyExpert,
    ThreadingExpert,
    CoffeeExpert,
    ToolHangExpert,
    MugHangExpert,
):
    register_expert(_cls)


def expert_class(task: str) -> type[Expert]:
    """The expert class of ``task`` (``"Lift"``, ``"StackThree_D1"``; ``-v0`` suffix accepted)."""
    key = task.removeprefix("lerobot_actionflow/").removesuffix("-v0")
    try:
        return EXPERTS[key]
    except KeyError:
        raise KeyError(f"no scripted expert for task {task!r}; experts exist for {sorted(EXPERTS)}") from None


def make_expert(task: str, env) -> Expert:
    """The expert of ``task`` bound to ``env`` (the unwrapped :class:`PoseTokenEnv`)."""
    return expert_class(task)(getattr(env, "unwrapped", env))


__all__ = ["EXPERTS", "Expert", "Waypoint", "WaypointExpert", "expert_class", "make_expert"]
