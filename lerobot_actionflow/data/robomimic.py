"""robomimic / mimicgen HDF5 demonstrations: the file layout, read and checked.

Layout (robomimic; mimicgen writes the same): group ``data`` with attribute ``env_args`` (JSON:
``env_name``, ``env_kwargs`` with ``controller_configs``) and groups ``data/demo_<i>``, each with
dataset ``actions`` ``(T, 7)`` ``[arm (6), gripper]`` and group ``obs`` holding ``(T, ...)``
datasets:

- ``robot0_eef_pos`` ``(T, 3)``: the grip site position (world frame);
- ``robot0_eef_quat`` ``(T, 4)``, scalar-last ``(x, y, z, w)``: the orientation of the *hand
  body* (robosuite reads it from the body, not from the grip site;
  :data:`~lerobot_actionflow.data.schema_arrays.R_HAND_TO_SITE` turns it into the grip site's);
- ``robot0_gripper_qpos`` ``(T, 2)``;
- per object token ``<prefix>_pos`` ``(T, 3)`` and ``<prefix>_quat`` ``(T, 4)`` (scalar-last), the
  prefix per task in :data:`OBS_PREFIX` (default: the token's name). Tokens that are fixed parts
  of the scene (:data:`STATIC_ENTITIES`: Can's goal cell, Square's peg) may be missing; their
  pose is then supplied by the caller.

The task comes from the caller or from ``env_name`` (robomimic names ``PickPlaceCan`` -> ``Can``,
``NutAssemblySquare`` -> ``Square``; mimicgen names such as ``StackThree_D1`` as is). Demos are
taken in the order of their number. ``states`` (flattened MuJoCo states) are not read: they
belong to the file's own model XML.

The arm controller config (``env_kwargs.controller_configs``; of a robosuite >= 1.5 composite
config, its ``body_parts.right``) gives the meaning of the arm actions:

- input type: ``input_type`` (robosuite >= 1.5, ``"delta"`` or ``"absolute"``) or else
  ``control_delta`` (robosuite <= 1.4 and robomimic, default true);
- reference frame: ``input_ref_frame`` (robosuite >= 1.5, ``"base"`` or ``"world"``; absent: the
  world frame of robosuite <= 1.4). A delta in the base frame equals one in the world frame
  when the robot base is not rotated, as in robosuite's and mimicgen's single-arm tasks.
  Absolute targets in the base frame are offset by the base position, which the file does not
  record: they are refused;
- delta scales ``s = output_max / input_max`` for position (m) and rotation (rad), default
  :data:`DEFAULT_SCALES` (robomimic's 0.05 m, 0.5 rad).

Errors: a missing group, dataset or observation key, or a malformed group (a dataset where a
group is expected, wrong shapes, mismatched lengths, non-finite values) raises ``ValueError``
naming it; so does a zero quaternion.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from lerobot_actionflow.rotations import xyzw_to_wxyz
from lerobot_actionflow.schema import GRIPPER_QPOS_DIM, POSE7_DIM

DATA_GROUP = "data"
OBS_GROUP = "obs"
ACTIONS = "actions"
EEF_POS = "robot0_eef_pos"
EEF_QUAT = "robot0_eef_quat"
GRIPPER_QPOS = "robot0_gripper_qpos"
#: Width of a robomimic action: ``[arm position (3), arm rotation (3), gripper]``.
SOURCE_ACTION_DIM = 7
#: The action modes a file's arm actions can have (see :mod:`.schema_arrays` for each one's
#: maths); ``next_pose`` ignores the arm actions.
ACTION_MODES = ("delta", "absolute", "next_pose")

#: robomimic / mimicgen env names that differ from our task names.
ENV_NAME_TO_TASK = {
    "Lift": "Lift",
    "PickPlaceCan": "Can",
    "NutAssemblySquare": "Square",
    "ToolHang": "ToolHang",
    "StackThree": "StackThree_D0",
    "Threading": "Threading_D0",
    "ThreePieceAssembly": "ThreePieceAssembly_D0",
    "Coffee": "Coffee_D0",
}
#: Per task: entity name -> prefix of its ``obs`` keys (``<prefix>_pos``, ``<prefix>_quat``).
OBS_PREFIX: dict[str, dict[str, str]] = {
    "Can": {"can": "Can"},
    "Square": {"nut": "SquareNut"},
    "ToolHang": {"stand": "base"},
}
#: Per task: entities fixed in the scene, whose pose the caller supplies when the obs lack them.
STATIC_ENTITIES: dict[str, tuple[str, ...]] = {"Can": ("goal",), "Square": ("peg",)}


@dataclass(frozen=True)
class DeltaScales:
    """``output_max / input_max`` of the arm controller: metres and radians per unit action."""

    position: float
    rotation: float


#: robomimic's OSC_POSE scales (0.05 m, 0.5 rad), used when the config gives none.
DEFAULT_SCALES = DeltaScales(0.05, 0.5)


@dataclass(frozen=True)
class SourcePlan:
    """What a file asks of the conversion: task, arm action mode and scales, demos in order."""

    env_name: str | None
    task: str
    action_mode: str
    delta_scales: DeltaScales
    demos: list[str]


@dataclass(frozen=True)
class SourceDemo:
    """One demo as read and checked, quaternions turned scalar-first (nothing else computed).

    Attributes:
        actions: ``(T, 7)`` ``[arm (6), gripper]`` as stored.
        eef_pos: ``(T, 3)`` grip site positions.
        hand_quat: ``(T, 4)`` ``(w, x, y, z)`` orientations of the hand body.
        gripper_qpos: ``(T, 2)`` finger positions.
        object_poses: ``(T, N - 1, 7)`` pose7 of the object tokens in the task's order.
    """

    actions: np.ndarray
    eef_pos: np.ndarray
    hand_quat: np.ndarray
    gripper_qpos: np.ndarray
    object_poses: np.ndarray


# ------------------------------------------------------------------ checked access
def group(parent, name: str, where: str):
    """``parent[name]``, which must be a group."""
    import h5py

    if name not in parent:
        raise ValueError(f"{where}: missing group '{name}'")
    g = parent[name]
    if not isinstance(g, h5py.Group):
        raise ValueError(f"{where}: malformed group '{name}' (a dataset where a group is expected)")
    return g


def dataset(
    parent, name: str, where: str, shape_tail: tuple[int, ...] | None, length: int | None
) -> np.ndarray:
    """``parent[name]`` as float64 ``(T, *shape_tail)`` (any tail if ``None``), finite, with
    ``length`` rows (any if ``None``)."""
    import h5py

    if name not in parent:
        raise ValueError(f"{where}: missing key '{name}'")
    d = parent[name]
    if not isinstance(d, h5py.Dataset):
        raise ValueError(f"{where}: malformed entry '{name}' (a group where a dataset is expected)")
    a = np.asarray(d[()], dtype=np.float64)
    if a.ndim < 1 or (shape_tail is not None and a.shape[1:] != shape_tail):
        raise ValueError(
            f"{where}/{name}: expected shape (T, {', '.join(map(str, shape_tail or ()))}), got {a.shape}"
        )
    if length is not None and a.shape[0] != length:
        raise ValueError(f"{where}/{name}: length {a.shape[0]} differs from the demo's {length} actions")
    bad = ~np.isfinite(a)
    if bad.any():
        t = int(np.argwhere(bad)[0][0])
        raise ValueError(f"{where}/{name}: non-finite value (NaN/inf) at frame {t}: {a[t].tolist()}")
    return a


def quaternions(parent, name: str, where: str, length: int) -> np.ndarray:
    """``parent[name]``: scalar-last quaternions ``(T, 4)``, none zero, returned scalar-first."""
    q = dataset(parent, name, where, (4,), length)
    norm = np.linalg.norm(q, axis=-1)
    bad = ~((norm >= 1e-12) & np.isfinite(norm))  # zero, or too large to normalise
    if bad.any():
        t = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{where}/{name}: zero quaternions (degenerate) at frame {t}: {q[t].tolist()}")
    return xyzw_to_wxyz(q)


# ------------------------------------------------------------------ file attributes
def env_args(data) -> dict[str, Any]:
    """The parsed ``env_args`` attribute of the ``data`` group (``{}`` if absent)."""
    raw = data.attrs.get("env_args")
    if raw is None:
        return {}
    try:
        return json.loads(raw if isinstance(raw, str) else bytes(raw).decode())
    except (json.JSONDecodeError, TypeError, UnicodeDecodeError) as e:
        raise ValueError(f"data.attrs['env_args'] is not valid JSON: {e}") from e


def arm_controller_config(args: dict) -> dict:
    """The arm part of ``env_kwargs.controller_configs`` (``body_parts.right`` of a composite)."""
    cc = args.get("env_kwargs", {}).get("controller_configs", {}) or {}
    if "body_parts" in cc:  # robosuite >= 1.5 composite config
        cc = cc["body_parts"].get("right", cc)
    return cc


def configured_action_mode(cc: dict) -> str:
    """``"delta"`` or ``"absolute"``, from ``input_type`` or else ``control_delta``."""
    if "input_type" in cc:
        if cc["input_type"] not in ("delta", "absolute"):
            raise ValueError(f"controller input_type {cc['input_type']!r} is neither 'delta' nor 'absolute'")
        return cc["input_type"]
    return "absolute" if cc.get("control_delta", True) is False else "delta"


def delta_scales(cc: dict) -> DeltaScales:
    """``output_max / input_max`` of the position (index 0) and rotation (index 3) inputs."""
    try:
        out = np.broadcast_to(np.asarray(cc["output_max"], dtype=np.float64), (6,))
        inp = np.broadcast_to(np.asarray(cc.get("input_max", 1.0), dtype=np.float64), (6,))
        return DeltaScales(float(out[0] / inp[0]), float(out[3] / inp[3]))
    except (KeyError, ValueError, TypeError):
        return DEFAULT_SCALES


def resolve_task(args: dict, task: str | None) -> str:
    """Our task name: ``task`` if given, else the one of ``env_args['env_name']``."""
    from lerobot_actionflow.envs.tasks import get_task

    if task is not None:
        return get_task(task).name
    name = args.get("env_name")
    if name is None:
        raise ValueError("data.attrs['env_args'] has no 'env_name' (missing key): pass --task")
    try:
        return get_task(ENV_NAME_TO_TASK.get(name, name)).name
    except KeyError:
        raise ValueError(f"env_name {name!r} is no known task: pass --task") from None


def demo_names(data) -> list[str]:
    """The ``demo_<i>`` groups of ``data``, by number."""
    names = [k for k in data if re.fullmatch(r"demo_\d+", k)]
    if not names:
        raise ValueError("group 'data' holds no 'demo_<i>' groups")
    return sorted(names, key=lambda k: int(k.split("_")[1]))


def read_plan(
    data, task: str | None = None, actions: str = "auto", max_demos: int | None = None
) -> SourcePlan:
    """The conversion's settings for the ``data`` group: ``actions`` is ``"auto"`` (the
    controller's input type) or one of :data:`ACTION_MODES`."""
    args = env_args(data)
    task_name = resolve_task(args, task)
    cc = arm_controller_config(args)
    mode = configured_action_mode(cc) if actions == "auto" else actions
    if mode not in ACTION_MODES:
        raise ValueError(f"unknown action mode {mode!r}: one of {', '.join(ACTION_MODES)}")
    if mode == "absolute" and cc.get("input_ref_frame", "world") != "world":
        raise ValueError(
            f"absolute actions in the controller's {cc['input_ref_frame']!r} frame are offset by the robot "
            "base pose, which the file does not record: convert with --actions next_pose"
        )
    return SourcePlan(
        env_name=args.get("env_name"),
        task=task_name,
        action_mode=mode,
        delta_scales=delta_scales(cc),
        demos=demo_names(data)[:max_demos],
    )


# ------------------------------------------------------------------ demos
def read_demo(data, name: str, task: str, static: dict[str, np.ndarray] | None = None) -> SourceDemo:
    """Read and check ``data/<name>`` of ``task``; ``static`` maps a fixed entity missing from
    the obs to its pose7."""
    from lerobot_actionflow.envs.tasks import get_task

    where = f"{DATA_GROUP}/{name}"
    demo = group(data, name, DATA_GROUP)
    actions = dataset(demo, ACTIONS, where, None, None)
    if actions.ndim != 2 or actions.shape[1] != SOURCE_ACTION_DIM:
        raise ValueError(
            f"{where}/{ACTIONS}: expected shape (T, {SOURCE_ACTION_DIM}) [dpos, drot, gripper], "
            f"got {actions.shape}"
        )
    t_len = actions.shape[0]
    obs = group(demo, OBS_GROUP, where)
    ow = f"{where}/{OBS_GROUP}"
    eef_pos = dataset(obs, EEF_POS, ow, (3,), t_len)
    hand_quat = quaternions(obs, EEF_QUAT, ow, t_len)
    gripper_qpos = dataset(obs, GRIPPER_QPOS, ow, (GRIPPER_QPOS_DIM,), t_len)
    prefixes, static = OBS_PREFIX.get(task, {}), static or {}
    objects = []
    for ent in get_task(task).entities:
        pre = prefixes.get(ent.name, ent.name)
        if ent.name in static and f"{pre}_pos" not in obs:
            pose = np.asarray(static[ent.name], dtype=np.float64)
            objects.append(np.broadcast_to(pose, (t_len, POSE7_DIM)))
            continue
        pos = dataset(obs, f"{pre}_pos", ow, (3,), t_len)
        quat = quaternions(obs, f"{pre}_quat", ow, t_len)
        objects.append(np.concatenate((pos, quat), axis=-1))
    object_poses = np.stack(objects, axis=1) if objects else np.zeros((t_len, 0, POSE7_DIM))
    return SourceDemo(actions, eef_pos, hand_quat, gripper_qpos, object_poses)
