"""The flat layout of a pose-token task as a LeRobot robot sees it: named scalar features.

LeRobot's deployment path (``lerobot-rollout``) takes from a robot only scalar ``float``
features whose names end in ``.pos`` or ``.vel`` (and camera images), and concatenates them, in
``observation_features`` order, into one ``observation.state`` vector; actions go the same way.
A pose-token task's observation (:mod:`lerobot_actionflow.schema`, ``N`` tokens) is therefore
exposed as ``16 N + 2`` named floats, three blocks in this order:

=============================  ==========================================  =================
block (schema key)             names                                       width
=============================  ==========================================  =================
``observation.state``          ``agent_pos.eef.<c9>.pos``,                 ``11``
                               ``agent_pos.gripper.q0.pos``, ``...q1.pos``
``observation.environment_     ``environment_state.<entity>.<c9>.pos``     ``9 (N - 1)``
state``                        (rows 1.. in task order)
``observation.poses``          ``poses.<token>.<c7>.pos`` (row-major,      ``7 N``
                               token ``eef`` then the entities)
=============================  ==========================================  =================

Each name starts with the env's observation key (``agent_pos``, ``environment_state``,
``poses``); not with ``state.``, which LeRobot strips from robot feature names when it builds
dataset features (``aggregate_pipeline_dataset_features``). ``<c9>`` runs over the pose9
components ``x y z r00 r10 r20 r01 r11 r21`` and ``<c7>`` over the pose7 components
``x y z qw qx qy qz``. The values are the env's own float32 numbers, so splitting the flat
vector (:func:`split_flat_observation`) gives back exactly the dataset's features. The action
is ``10`` named floats ``target.<c9>.pos`` then ``gripper.pos``, in the schema's action order
``[x, y, z, rot6d, gripper]``.

Torch-free: the split works on numpy arrays and torch tensors alike (slicing and reshaping of
the last axis).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from lerobot_actionflow.envs.tasks import TaskSpec
from lerobot_actionflow.schema import (
    ACTION_DIM,
    ENV_AGENT_POS,
    ENV_POSES,
    ENV_STATE,
    ENV_STATE_KEY,
    GRIPPER_QPOS_DIM,
    POSE7_DIM,
    POSE9_DIM,
    POSES_KEY,
    STATE_DIM,
    STATE_KEY,
    env_state_dim,
)

#: LeRobot's rollout keeps scalar robot features only under this suffix (or ``.vel``).
SUFFIX = ".pos"
POSE9_COMPONENTS = ("x", "y", "z", "r00", "r10", "r20", "r01", "r11", "r21")
POSE7_COMPONENTS = ("x", "y", "z", "qw", "qx", "qy", "qz")
EEF_TOKEN = "eef"
assert len(POSE9_COMPONENTS) == POSE9_DIM and len(POSE7_COMPONENTS) == POSE7_DIM


def flat_width(num_tokens: int) -> int:
    """Width ``16 N + 2`` of the flat observation of a task with ``num_tokens`` poses."""
    return STATE_DIM + env_state_dim(num_tokens) + POSE7_DIM * num_tokens


def observation_names(spec: TaskSpec) -> list[str]:
    """The flat observation's feature names, in vector order (see the module table)."""
    entities = [e.name for e in spec.entities]
    names = [f"{ENV_AGENT_POS}.{EEF_TOKEN}.{c}{SUFFIX}" for c in POSE9_COMPONENTS]
    names += [f"{ENV_AGENT_POS}.gripper.q{i}{SUFFIX}" for i in range(GRIPPER_QPOS_DIM)]
    names += [f"{ENV_STATE}.{e}.{c}{SUFFIX}" for e in entities for c in POSE9_COMPONENTS]
    names += [f"{ENV_POSES}.{t}.{c}{SUFFIX}" for t in (EEF_TOKEN, *entities) for c in POSE7_COMPONENTS]
    if len(set(names)) != len(names):
        raise ValueError(f"task {spec.name}: entity names give duplicate feature names: {entities}")
    return names


def action_names() -> list[str]:
    """The action's feature names, in the schema's order ``[x, y, z, rot6d, gripper]``."""
    return [f"target.{c}{SUFFIX}" for c in POSE9_COMPONENTS] + [f"gripper{SUFFIX}"]


def flatten_observation(obs: Mapping[str, Any], names: list[str]) -> dict[str, float]:
    """The env observation (``agent_pos``, ``environment_state``, ``poses``) as named floats."""
    flat = np.concatenate(
        [np.ravel(obs[ENV_AGENT_POS]), np.ravel(obs[ENV_STATE]), np.ravel(obs[ENV_POSES])]
    ).tolist()
    if len(flat) != len(names):
        raise ValueError(f"observation has {len(flat)} values, the layout {len(names)} names")
    return dict(zip(names, flat, strict=True))


def split_flat_observation(flat, num_tokens: int) -> dict[str, Any]:
    """``(..., 16 N + 2)`` flat observation -> ``observation.state (..., 11)``,
    ``observation.environment_state (..., 9 (N - 1))`` and ``observation.poses (..., N, 7)``
    (views of ``flat``; numpy array or torch tensor)."""
    width = flat_width(num_tokens)
    if flat.shape[-1] != width:
        raise ValueError(
            f"flat robot observation for {num_tokens} pose tokens must have last dimension {width} "
            f"(state {STATE_DIM} + environment_state {env_state_dim(num_tokens)} + poses "
            f"{num_tokens}x{POSE7_DIM}), got shape {tuple(flat.shape)}"
        )
    a, b = STATE_DIM, STATE_DIM + env_state_dim(num_tokens)
    return {
        STATE_KEY: flat[..., :a],
        ENV_STATE_KEY: flat[..., a:b],
        POSES_KEY: flat[..., b:].reshape(*flat.shape[:-1], num_tokens, POSE7_DIM),
    }


def action_from_dict(action: Mapping[str, Any]) -> np.ndarray:
    """Named action floats -> the schema's action ``float64 (10,)``.

    Raises:
        ValueError: not a mapping, a missing or unknown key, or a non-numeric / non-finite value.
    """
    names = action_names()
    if not isinstance(action, Mapping):
        raise ValueError(f"action must be a dict of {ACTION_DIM} floats {names}, got {type(action).__name__}")
    missing = [k for k in names if k not in action]
    unknown = sorted(set(action) - set(names))
    if missing or unknown:
        raise ValueError(
            f"action keys must be exactly {names} ([x, y, z, rot6d, gripper], absolute EEF target); "
            f"missing {missing}, unknown {unknown}"
        )
    out = np.empty(ACTION_DIM)
    for i, k in enumerate(names):
        try:
            out[i] = float(action[k])
        except (TypeError, ValueError) as e:
            raise ValueError(f"action {k!r} must be a number, got {action[k]!r}") from e
        if not np.isfinite(out[i]):
            raise ValueError(f"action {k!r} is not finite: {out[i]}")
    return out
