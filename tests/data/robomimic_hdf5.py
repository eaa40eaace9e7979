"""Small HDF5 files in robomimic's layout (written by the tests, no real dataset needed)."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np


def random_quat_xyzw(rng, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def write_robomimic_hdf5(path: Path, env_args: dict, demos: list[dict[str, np.ndarray]]) -> None:
    """Write ``demos`` in robomimic's layout: each a dict with ``actions`` ``(T, 7)``, ``states``
    ``(T, S)`` and the ``obs`` datasets under their robomimic keys; ``rewards`` and ``dones`` are
    zeros and ``next_obs`` is left out (the converter reads neither)."""
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["env_args"] = json.dumps(env_args)
        data.attrs["total"] = sum(len(d["actions"]) for d in demos)
        for i, arrays in enumerate(demos):
            g = data.create_group(f"demo_{i}")
            length = len(arrays["actions"])
            g.attrs["num_samples"] = length
            obs = g.create_group("obs")
            for k, v in arrays.items():
                if k not in ("actions", "states"):
                    obs.create_dataset(k, data=v)
            g.create_dataset("actions", data=arrays["actions"])
            g.create_dataset("states", data=arrays["states"])
            g.create_dataset("rewards", data=np.zeros(length))
            g.create_dataset("dones", data=np.zeros(length))


def write_lift_hdf5(path: Path, demos: int = 2, length: int = 6, seed: int = 0, delta: bool = True) -> dict:
    """A robomimic-style Lift file of random values; returns the arrays written, per demo name."""
    rng = np.random.default_rng(seed)
    env_args = {
        "env_name": "Lift",
        "env_type": 1,
        "env_kwargs": {
            "controller_configs": {
                "type": "OSC_POSE",
                "input_max": 1,
                "input_min": -1,
                "output_max": [0.05, 0.05, 0.05, 0.5, 0.5, 0.5],
                "output_min": [-0.05, -0.05, -0.05, -0.5, -0.5, -0.5],
                "control_delta": delta,
            }
        },
    }
    written = []
    for _ in range(demos):
        arrays = {
            "robot0_eef_pos": rng.uniform(-0.2, 0.2, (length, 3)) + np.array([0, 0, 1.0]),
            "robot0_eef_quat": random_quat_xyzw(rng, length),
            "robot0_gripper_qpos": rng.uniform(-0.04, 0.04, (length, 2)),
            "cube_pos": rng.uniform(-0.1, 0.1, (length, 3)) + np.array([0, 0, 0.82]),
            "cube_quat": random_quat_xyzw(rng, length),
        }
        actions = np.concatenate(
            [rng.uniform(-1.2, 1.2, (length, 6)), np.where(rng.random((length, 1)) < 0.5, -1.0, 1.0)], 1
        )
        written.append({**arrays, "actions": actions, "states": rng.normal(size=(length, 10))})
    write_robomimic_hdf5(path, env_args, written)
    return {f"demo_{i}": {k: v for k, v in d.items() if k != "states"} for i, d in enumerate(written)}
