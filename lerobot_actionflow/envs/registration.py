"""Gymnasium ids ``lerobot_actionflow/<Task>-v0`` for every task in the registry.

Registration imports nothing heavy: the entry point is a string, so robosuite is imported at
the first ``gym.make``. ``max_episode_steps`` is the task's episode length (``gym.make`` wraps the
env in ``TimeLimit``; pass ``max_episode_steps=`` to ``gym.make`` to override it).
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from lerobot_actionflow.envs.tasks import TASKS

ENTRY_POINT = "lerobot_actionflow.envs.pose_env:PoseTokenEnv"


def register_gym_envs() -> list[str]:
    """Register every task of :data:`TASKS` not registered yet; returns all our gym ids."""
    ids = []
    for spec in TASKS.values():
        if spec.gym_id not in registry:
            register(
                id=spec.gym_id,
                entry_point=ENTRY_POINT,
                max_episode_steps=spec.episode_length,
                kwargs={"task": spec.name},
            )
        ids.append(spec.gym_id)
    return ids
