"""``actionflow-convert``: robomimic / mimicgen HDF5 demonstrations into a LeRobotDataset.

    actionflow-convert INPUT.hdf5 --root DIR [--task T] [--repo-id ID]
                       [--actions auto|delta|absolute|next_pose] [--max-demos K]

Input layout (robomimic; mimicgen writes the same): group ``data`` with attribute ``env_args``
(JSON: ``env_name``, ``env_kwargs`` with ``controller_configs``) and groups ``data/demo_<i>``,
each with dataset ``actions`` ``(T, 7)`` and group ``obs`` holding ``(T, ...)`` datasets:

- ``robot0_eef_pos`` ``(T, 3)``: the grip site position (world frame);
- ``robot0_eef_quat`` ``(T, 4)``, **scalar-last** ``(x, y, z, w)``: orientation of the hand
  body, which robosuite's grip site (our EEF token) is turned from by -90 deg about the hand's
  z axis: ``R_eef = R_hand R_HAND_TO_SITE`` (measured on robosuite 1.5.2);
- ``robot0_gripper_qpos`` ``(T, 2)``;
- per object token ``<prefix>_pos`` ``(T, 3)`` and ``<prefix>_quat`` ``(T, 4)`` (scalar-last), the
  prefix per task in :data:`OBS_PREFIX` (default: the token's name). Tokens that are fixed parts
  of the scene (Can's goal cell, Square's peg) are read from our env after a reset.

The task comes from ``--task`` or from ``env_name`` (robomimic names ``PickPlaceCan`` ->
``Can``, ``NutAssemblySquare`` -> ``Square``; mimicgen names such as ``StackThree_D1`` as is).
Demos are converted in the order of their number; each becomes one episode of ``T`` frames.

Actions (``--actions``; ``auto`` picks ``absolute`` when the controller config says
``control_delta: false``, else ``delta``). The output is the schema's absolute EEF target
``[x, y, z, rot6d, gripper]``; the gripper value is copied (-1 open, +1 closed, as robosuite):

- ``delta``: robosuite's OSC_POSE delta mode, integrated from the observed pose:
  ``p* = p_t + s_p clip(a[:3], -1, 1)``, ``R* = Exp(s_r clip(a[3:6], -1, 1)) R_t`` (the rotation
  delta is axis-angle in the world frame, applied on the left), with ``s_p``, ``s_r`` the
  controller's ``output_max / input_max`` (robomimic: 0.05 m and 0.5 rad). This is the target
  the controller was given at step ``t``.
- ``absolute``: actions already ``[pos, axis-angle, gripper]`` in the world frame (the axis-angle
  is of the grip site's orientation).
- ``next_pose``: ignore the arm actions and use the observed EEF pose at ``t + 1`` (the last
  step repeats its own pose).

Errors: a missing group, dataset or observation key, or a malformed group (a dataset where a
group is expected, wrong shapes, mismatched lengths) raises ``ValueError`` naming it. The
dataset is written to a temporary sibling folder and moved to ``--root`` only when every demo
converted, so a failure leaves nothing behind. ``--root`` must not exist.
State replay (``states``) is not used: robomimic's MuJoCo states belong to its own model XML.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import re
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

#: Grip-site orientation in the hand body's frame (``R_site = R_hand @ R_HAND_TO_SITE``).
R_HAND_TO_SITE = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
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
#: Per task: entities fixed in the scene, read from our env when the obs lack them.
STATIC_ENTITIES: dict[str, tuple[str, ...]] = {"Can": ("goal",), "Square": ("peg",)}
DEFAULT_SCALE = (0.05, 0.5)
META_FILE = "actionflow_convert.json"


# ------------------------------------------------------------------ numpy geometry
def xyzw_to_wxyz(q: np.ndarray) -> np.ndarray:
    return np.concatenate([q[..., 3:4], q[..., :3]], axis=-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Scalar-first quaternions ``(..., 4)`` -> rotation matrices ``(..., 3, 3)``."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` -> scalar-first quaternions with ``w >= 0``."""
    from lerobot_actionflow.envs import rotations as rot

    flat = r.reshape(-1, 3, 3)
    out = np.stack([rot.matrix_to_quat(m) for m in flat])
    return out.reshape(*r.shape[:-2], 4)


def axis_angle_to_matrix(v: np.ndarray) -> np.ndarray:
    """Rodrigues, batched: ``(..., 3)`` -> ``(..., 3, 3)``."""
    th = np.linalg.norm(v, axis=-1, keepdims=True)
    k = np.where(th > 1e-12, v / np.maximum(th, 1e-12), 0.0)
    kx = np.zeros((*v.shape[:-1], 3, 3))
    kx[..., 0, 1], kx[..., 0, 2], kx[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    kx[..., 1, 0], kx[..., 2, 0], kx[..., 2, 1] = k[..., 2], -k[..., 1], k[..., 0]
    s, c = np.sin(th)[..., None], np.cos(th)[..., None]
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def rot6d(r: np.ndarray) -> np.ndarray:
    return np.concatenate([r[..., :, 0], r[..., :, 1]], axis=-1)


# ------------------------------------------------------------------ reading
def _group(parent, name: str, where: str):
    import h5py

    if name not in parent:
        raise ValueError(f"{where}: missing group '{name}'")
    g = parent[name]
    if not isinstance(g, h5py.Group):
        raise ValueError(f"{where}: malformed group '{name}' (a dataset where a group is expected)")
    return g


def _dataset(parent, name: str, where: str, shape_tail: tuple[int, ...] | None, length: int | None):
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
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{where}/{name}: non-finite values")
    return a


def _env_args(data) -> dict[str, Any]:
    raw = data.attrs.get("env_args")
    if raw is None:
        return {}
    try:
        return json.loads(raw if isinstance(raw, str) else bytes(raw).decode())
    except (json.JSONDecodeError, TypeError, UnicodeDecodeError) as e:
        raise ValueError(f"data.attrs['env_args'] is not valid JSON: {e}") from e


def _controller(env_args: dict) -> dict:
    cc = env_args.get("env_kwargs", {}).get("controller_configs", {}) or {}
    if "body_parts" in cc:  # robosuite >= 1.5 composite config
        cc = cc["body_parts"].get("right", cc)
    return cc


def _scales(cc: dict) -> tuple[float, float]:
    try:
        out = np.broadcast_to(np.asarray(cc["output_max"], dtype=np.float64), (6,))
        inp = np.broadcast_to(np.asarray(cc.get("input_max", 1.0), dtype=np.float64), (6,))
        return float(out[0] / inp[0]), float(out[3] / inp[3])
    except (KeyError, ValueError, TypeError):
        return DEFAULT_SCALE


def resolve_task(env_args: dict, task: str | None) -> str:
    from lerobot_actionflow.envs.tasks import get_task

    if task is not None:
        return get_task(task).name
    name = env_args.get("env_name")
    if name is None:
        raise ValueError("data.attrs['env_args'] has no 'env_name' (missing key): pass --task")
    try:
        return get_task(ENV_NAME_TO_TASK.get(name, name)).name
    except KeyError:
        raise ValueError(f"env_name {name!r} is no known task: pass --task") from None


def demo_names(data) -> list[str]:
    names = [k for k in data if re.fullmatch(r"demo_\d+", k)]
    if not names:
        raise ValueError("group 'data' holds no 'demo_<i>' groups")
    return sorted(names, key=lambda k: int(k.split("_")[1]))


def _static_poses(task: str, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    import gymnasium as gym

    import lerobot_actionflow.envs  # noqa: F401
    from lerobot_actionflow.envs.tasks import get_task

    spec = get_task(task)
    env = gym.make(spec.gym_id, render_mode=None)
    try:
        obs, _ = env.reset(seed=0)
    finally:
        env.close()
    order = [e.name for e in spec.entities]
    return {n: np.asarray(obs["poses"][1 + order.index(n)], dtype=np.float64) for n in names}


def convert_demo(demo, where: str, task: str, mode: str, scales, static: dict) -> dict[str, np.ndarray]:
    """Arrays of one demo in the schema: poses ``(T, N, 7)``, state ``(T, 11)``,
    environment_state ``(T, 9 (N-1))``, action ``(T, 10)``."""
    from lerobot_actionflow.envs.tasks import get_task

    spec = get_task(task)
    actions = _dataset(demo, "actions", where, None, None)
    if actions.ndim != 2 or actions.shape[1] != 7:
        raise ValueError(f"{where}/actions: expected shape (T, 7) [dpos, drot, gripper], got {actions.shape}")
    t_len = actions.shape[0]
    obs = _group(demo, "obs", where)
    ow = f"{where}/obs"
    eef_p = _dataset(obs, "robot0_eef_pos", ow, (3,), t_len)
    eef_r = quat_to_matrix(xyzw_to_wxyz(_dataset(obs, "robot0_eef_quat", ow, (4,), t_len))) @ R_HAND_TO_SITE
    grip = _dataset(obs, "robot0_gripper_qpos", ow, (2,), t_len)
    prefixes = OBS_PREFIX.get(task, {})
    obj_p, obj_r = [], []
    for ent in spec.entities:
        pre = prefixes.get(ent.name, ent.name)
        if ent.name in static and f"{pre}_pos" not in obs:
            pose = static[ent.name]
            obj_p.append(np.broadcast_to(pose[:3], (t_len, 3)))
            obj_r.append(np.broadcast_to(quat_to_matrix(pose[3:]), (t_len, 3, 3)))
            continue
        obj_p.append(_dataset(obs, f"{pre}_pos", ow, (3,), t_len))
        obj_r.append(quat_to_matrix(xyzw_to_wxyz(_dataset(obs, f"{pre}_quat", ow, (4,), t_len))))
    pos = np.stack([eef_p, *obj_p], axis=1)  # (T, N, 3)
    rmat = np.stack([eef_r, *obj_r], axis=1)  # (T, N, 3, 3)
    poses = np.concatenate([pos, matrix_to_quat(rmat)], axis=-1)
    state = np.concatenate([eef_p, rot6d(eef_r), grip], axis=-1)
    env_state = np.concatenate([pos[:, 1:], rot6d(rmat[:, 1:])], axis=-1).reshape(t_len, -1)

    a = actions
    if mode == "delta":
        c = np.clip(a[:, :6], -1.0, 1.0)
        tgt_p = eef_p + scales[0] * c[:, :3]
        tgt_r = axis_angle_to_matrix(scales[1] * c[:, 3:6]) @ eef_r
    elif mode == "absolute":
        tgt_p, tgt_r = a[:, :3], axis_angle_to_matrix(a[:, 3:6])
    elif mode == "next_pose":
        nxt = np.r_[1:t_len, t_len - 1]
        tgt_p, tgt_r = eef_p[nxt], eef_r[nxt]
    else:
        raise ValueError(f"unknown action mode {mode!r}")
    action = np.concatenate([tgt_p, rot6d(tgt_r), np.clip(a[:, 6:7], -1.0, 1.0)], axis=-1)
    return {
        "observation.poses": poses.astype(np.float32),
        "observation.state": state.astype(np.float32),
        "observation.environment_state": env_state.astype(np.float32),
        "action": action.astype(np.float32),
    }


def convert(
    input_path: str | Path,
    root: str | Path,
    task: str | None = None,
    repo_id: str | None = None,
    actions: str = "auto",
    max_demos: int | None = None,
) -> dict[str, Any]:
    """Convert ``input_path`` into a LeRobotDataset at ``root`` (see the module docstring).
    Returns the conversion metadata (also written to ``meta/actionflow_convert.json``)."""
    import h5py

    from lerobot_actionflow.data.features import schema_features
    from lerobot_actionflow.envs.tasks import CONTROL_FREQ, get_task

    input_path, root = Path(input_path), Path(root)
    if root.exists():
        raise ValueError(f"--root {root} already exists: choose a new folder")
    if not input_path.is_file():
        raise ValueError(f"input file {input_path} does not exist")
    try:
        f = h5py.File(input_path, "r")
    except OSError as e:
        raise ValueError(f"{input_path} is not a readable HDF5 file: {e}") from e
    with f:
        data = _group(f, "data", str(input_path))
        env_args = _env_args(data)
        task_name = resolve_task(env_args, task)
        spec = get_task(task_name)
        cc = _controller(env_args)
        mode = actions
        if mode == "auto":
            mode = "absolute" if cc.get("control_delta", True) is False else "delta"
        scales = _scales(cc)
        names = demo_names(data)[:max_demos]
        static_names = STATIC_ENTITIES.get(task_name, ())
        static = _static_poses(task_name, static_names) if static_names else {}
        repo_id = repo_id or f"local/{task_name.lower()}"
        root.parent.mkdir(parents=True, exist_ok=True)
        tmp_parent = Path(tempfile.mkdtemp(prefix=f".{root.name}.", dir=root.parent))
        tmp = tmp_parent / "dataset"
        try:
            from lerobot.datasets.lerobot_dataset import LeRobotDataset

            ds = LeRobotDataset.create(
                repo_id=repo_id,
                fps=CONTROL_FREQ,
                features=schema_features(spec.num_tokens),
                root=tmp,
                use_videos=False,
            )
            lengths = []
            try:
                for name in names:
                    demo = _group(data, name, "data")
                    arrays = convert_demo(demo, f"data/{name}", task_name, mode, scales, static)
                    t_len = arrays["action"].shape[0]
                    for t in range(t_len):
                        ds.add_frame({**{k: v[t] for k, v in arrays.items()}, "task": spec.description})
                    ds.save_episode()
                    lengths.append(t_len)
            finally:
                ds.finalize()
            meta = {
                "source": str(input_path.resolve()),
                "env_name": env_args.get("env_name"),
                "task": task_name,
                "variant": spec.variant,
                "action_mode": mode,
                "delta_scales": {"position": scales[0], "rotation": scales[1]},
                "demos": names,
                "lengths": lengths,
                "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            }
            (tmp / "meta" / META_FILE).write_text(json.dumps(meta, indent=2))
            tmp.rename(root)
        finally:
            shutil.rmtree(tmp_parent, ignore_errors=True)
    return meta


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="actionflow-convert",
        description="Convert a robomimic/mimicgen HDF5 file into a LeRobotDataset in the project's schema.",
    )
    p.add_argument("input", help="robomimic/mimicgen HDF5 file")
    p.add_argument("--root", required=True, help="output dataset folder (must not exist)")
    p.add_argument("--task", default=None, help="our task name (default: from env_args' env_name)")
    p.add_argument("--repo-id", default=None, help="dataset repo id (default local/<task>)")
    p.add_argument("--actions", choices=("auto", "delta", "absolute", "next_pose"), default="auto")
    p.add_argument("--max-demos", type=int, default=None, help="convert only the first K demos")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        meta = convert(args.input, args.root, args.task, args.repo_id, args.actions, args.max_demos)
    except (ValueError, KeyError) as e:
        print(f"actionflow-convert: error: {e}", file=sys.stderr)
        return 2
    print(
        f"{meta['task']}: {len(meta['demos'])} demos ({sum(meta['lengths'])} frames) -> {args.root} "
        f"(actions: {meta['action_mode']})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
