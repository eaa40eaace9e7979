"""``actionflow-convert``: robomimic / mimicgen HDF5 demonstrations into a LeRobotDataset.

    actionflow-convert INPUT.hdf5 --root DIR [--task T] [--repo-id ID]
                       [--actions auto|delta|absolute|next_pose] [--max-demos K]

Each demo becomes one episode of ``T`` frames in the schema (:mod:`lerobot_actionflow.schema`),
at the env's control frequency, without images. :mod:`.robomimic` reads and checks the file
(layout, task, controller settings; ``--actions auto`` takes the controller's input type);
:mod:`.schema_arrays` computes the poses, states and absolute EEF target actions. Fixed scene
entities the file lacks (:data:`~.robomimic.STATIC_ENTITIES`) are read from our env after a
reset with seed 0.

Errors raise ``ValueError`` naming the group, dataset or key (the CLI prints it and exits with
status 2); a NaN / inf in any input array, a zero quaternion, or an output that overflows float32
is named with the file, demo, key and first bad frame. The dataset is written to a temporary
sibling folder and moved to ``--root`` only when every demo converted, so a failure leaves
nothing behind. ``--root`` must not exist.
``meta/actionflow_convert.json`` records the source, task, action mode, delta scales, demos and
their lengths.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import json
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from lerobot_actionflow.data.features import default_repo_id, schema_features
from lerobot_actionflow.data.robomimic import (
    ACTION_MODES,
    DATA_GROUP,
    STATIC_ENTITIES,
    group,
    read_demo,
    read_plan,
)
from lerobot_actionflow.data.schema_arrays import schema_arrays
from lerobot_actionflow.schema import ACTION_KEY, ENV_POSES

META_FILE = "actionflow_convert.json"


def static_poses(task: str, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Pose7 of the fixed entities ``names`` of ``task`` in our env after ``reset(seed=0)``."""
    import gymnasium as gym

    import lerobot_actionflow.envs  # noqa: F401  (gym ids)
    from lerobot_actionflow.envs.tasks import get_task

    spec = get_task(task)
    env = gym.make(spec.gym_id, render_mode=None)
    try:
        obs, _ = env.reset(seed=0)
    finally:
        env.close()
    order = [e.name for e in spec.entities]
    return {n: np.asarray(obs[ENV_POSES][1 + order.index(n)], dtype=np.float64) for n in names}


def check_finite(arrays: dict[str, np.ndarray], where: str) -> None:
    """Raise ``ValueError`` naming the key and first frame of a non-finite schema value (finite
    inputs can overflow float32, e.g. a position of 1e39)."""
    for key, a in arrays.items():
        bad = ~np.isfinite(a.reshape(len(a), -1)).all(axis=1)
        if bad.any():
            t = int(np.flatnonzero(bad)[0])
            raise ValueError(f"{where}: output {key} is non-finite (NaN/inf) at frame {t}: {a[t].tolist()}")


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

    from lerobot_actionflow.envs.tasks import CONTROL_FREQ, get_task

    input_path, root = Path(input_path), Path(root)
    if root.exists():
        raise ValueError(f"--root {root} already exists: choose a new folder")
    if input_path.is_dir():
        raise ValueError(f"input {input_path} is a directory: give the HDF5 file")
    if not input_path.is_file():
        raise ValueError(f"input file {input_path} does not exist")
    try:
        f = h5py.File(input_path, "r")
    except OSError as e:
        raise ValueError(f"{input_path} is not a readable HDF5 file: {e}") from e
    with f:
        data = group(f, DATA_GROUP, str(input_path))
        plan = read_plan(data, task, actions, max_demos)
        spec = get_task(plan.task)
        static_names = STATIC_ENTITIES.get(plan.task, ())
        static = static_poses(plan.task, static_names) if static_names else {}
        root.parent.mkdir(parents=True, exist_ok=True)
        tmp_parent = Path(tempfile.mkdtemp(prefix=f".{root.name}.", dir=root.parent))
        tmp = tmp_parent / "dataset"
        try:
            from lerobot.datasets.lerobot_dataset import LeRobotDataset

            ds = LeRobotDataset.create(
                repo_id=repo_id or default_repo_id(plan.task),
                fps=CONTROL_FREQ,
                features=schema_features(spec.num_tokens),
                root=tmp,
                use_videos=False,
            )
            lengths = []
            try:
                for name in plan.demos:
                    try:
                        demo = read_demo(data, name, plan.task, static)
                        arrays = schema_arrays(demo, plan.action_mode, plan.delta_scales)
                        check_finite(arrays, f"{DATA_GROUP}/{name}")
                    except ValueError as e:
                        raise ValueError(f"{input_path}: {e}") from None
                    t_len = arrays[ACTION_KEY].shape[0]
                    for t in range(t_len):
                        ds.add_frame({**{k: v[t] for k, v in arrays.items()}, "task": spec.description})
                    ds.save_episode()
                    lengths.append(t_len)
            finally:
                ds.finalize()
            meta = {
                "source": str(input_path.resolve()),
                "env_name": plan.env_name,
                "task": plan.task,
                "variant": spec.variant,
                "action_mode": plan.action_mode,
                "delta_scales": dataclasses.asdict(plan.delta_scales),
                "demos": plan.demos,
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
    p.add_argument(
        "--actions",
        choices=("auto", *ACTION_MODES),
        default="auto",
        help="how to read the arm actions (default: the controller's input type)",
    )
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
