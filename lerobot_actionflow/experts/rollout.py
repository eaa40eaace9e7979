"""Run a scripted expert for one episode in a pose-token env.

The episode of seed ``s`` is fully determined by ``s``: the env is reset with ``seed=s`` and the
expert draws its random choices from ``np.random.default_rng(s)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class Episode:
    """``observations[t]`` is what the expert saw when it chose ``actions[t]``."""

    seed: int
    success: bool = False
    interrupted: bool = False
    #: Env steps taken (also when ``record=False``).
    steps: int = 0
    observations: list[dict[str, Any]] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.actions)


def run_episode(
    env,
    expert,
    seed: int,
    max_steps: int | None = None,
    record: bool = True,
    stop: Callable[[], bool] | None = None,
) -> Episode:
    """Reset ``env`` with ``seed``, act with ``expert`` until success, truncation or ``max_steps``
    (default: the task's episode length). ``record=False`` keeps no frames (benchmarks).
    ``stop()`` is polled every step; when it returns true the episode ends with
    ``interrupted=True`` (used for a clean Ctrl-C during collection)."""
    spec = env.unwrapped.spec_task
    limit = spec.episode_length if max_steps is None else max_steps
    obs, _ = env.reset(seed=int(seed))
    expert.reset(np.random.default_rng(int(seed)))
    ep = Episode(seed=int(seed))
    for _ in range(limit):
        if stop is not None and stop():
            ep.interrupted = True
            break
        action = expert.act(obs)
        if record:
            ep.observations.append(obs)
            ep.actions.append(action)
        obs, _, terminated, truncated, info = env.step(action)
        ep.steps += 1
        if info.get("is_success", False):
            ep.success = True
            break
        if terminated or truncated:
            break
    return ep
