"""``actionflow-convert``: robomimic HDF5 -> LeRobotDataset, values and error handling."""

from __future__ import annotations

import subprocess

import h5py
import numpy as np
import pytest
import torch

from lerobot_actionflow import geometry as g
from lerobot_actionflow.data.convert import R_HAND_TO_SITE, convert, main
from tests.data.conftest import BIN, cli_env
from tests.data.robomimic_hdf5 import write_lift_hdf5


def _load(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset("local/lift", root=root)


def _episode(ds, e):
    idx = [i for i in range(len(ds)) if int(ds[i]["episode_index"]) == e]
    return {
        k: torch.stack([ds[i][k] for i in idx]).double()
        for k in ("observation.poses", "observation.state", "action")
    }


def _rot(q_xyzw):
    return g.quaternion_to_matrix(g.xyzw_to_wxyz(torch.as_tensor(q_xyzw, dtype=torch.float64)))


def test_round_trip_converts_quaternions_keeps_positions_and_integrates_deltas(tmp_path):
    src = tmp_path / "lift.hdf5"
    written = write_lift_hdf5(src, demos=2, length=6)
    root = tmp_path / "out"
    proc = subprocess.run(
        [str(BIN / "actionflow-convert"), str(src), "--root", str(root)],
        capture_output=True, text=True, timeout=120, env=cli_env(),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    ds = _load(root)
    assert ds.num_episodes == 2 and len(ds) == 12
    for e in range(2):
        w = {k: torch.as_tensor(v, dtype=torch.float64) for k, v in written[f"demo_{e}"].items()}
        ep = _episode(ds, e)
        poses = ep["observation.poses"]
        # Positions are kept.
        torch.testing.assert_close(poses[:, 0, :3], w["robot0_eef_pos"], atol=1e-6, rtol=0)
        torch.testing.assert_close(poses[:, 1, :3], w["cube_pos"], atol=1e-6, rtol=0)
        # Object quaternion: xyzw -> wxyz (same rotation; w >= 0 sign convention).
        q_cube = poses[:, 1, 3:]
        q_ref = g.xyzw_to_wxyz(w["cube_quat"])
        q_ref = q_ref * torch.sign(q_ref[:, :1])
        torch.testing.assert_close(q_cube, q_ref, atol=1e-5, rtol=0)
        # EEF: the hand quaternion turned to the grip site frame.
        r_site = _rot(w["robot0_eef_quat"]) @ torch.as_tensor(R_HAND_TO_SITE)
        torch.testing.assert_close(g.quaternion_to_matrix(poses[:, 0, 3:]), r_site, atol=1e-5, rtol=0)
        torch.testing.assert_close(
            ep["observation.state"][:, 3:9], g.matrix_to_rotation_6d(r_site), atol=1e-5, rtol=0
        )
        torch.testing.assert_close(
            ep["observation.state"][:, 9:], w["robot0_gripper_qpos"], atol=1e-6, rtol=0
        )
        # Delta actions -> absolute targets with robomimic's scaling (0.05 m, 0.5 rad), clipped to [-1, 1].
        a = w["actions"].clamp(-1, 1)
        torch.testing.assert_close(
            ep["action"][:, :3], w["robot0_eef_pos"] + 0.05 * a[:, :3], atol=1e-6, rtol=0
        )
        r_tgt = g.exp(0.5 * a[:, 3:6]) @ r_site
        torch.testing.assert_close(ep["action"][:, 3:9], g.matrix_to_rotation_6d(r_tgt), atol=1e-5, rtol=0)
        torch.testing.assert_close(ep["action"][:, 9], w["actions"][:, 6], atol=0, rtol=0)


def test_absolute_controller_actions_are_copied(tmp_path):
    src = tmp_path / "lift.hdf5"
    written = write_lift_hdf5(src, demos=1, length=4, delta=False)
    root = tmp_path / "out"
    meta = convert(src, root)
    assert meta["action_mode"] == "absolute"
    ep = _episode(_load(root), 0)
    a = torch.as_tensor(written["demo_0"]["actions"])
    torch.testing.assert_close(ep["action"][:, :3], a[:, :3], atol=1e-6, rtol=0)
    torch.testing.assert_close(
        ep["action"][:, 3:9], g.matrix_to_rotation_6d(g.exp(a[:, 3:6])), atol=1e-5, rtol=0
    )


def _assert_nothing_written(tmp_path, root):
    assert not root.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lift.hdf5"], list(tmp_path.iterdir())


def test_missing_obs_key_names_it_and_writes_nothing(tmp_path):
    src = tmp_path / "lift.hdf5"
    write_lift_hdf5(src, demos=3, length=4)
    with h5py.File(src, "a") as f:
        del f["data/demo_2/obs/robot0_eef_quat"]  # after two good demos were written
    root = tmp_path / "out"
    with pytest.raises(ValueError, match=r"data/demo_2/obs: missing key 'robot0_eef_quat'"):
        convert(src, root)
    _assert_nothing_written(tmp_path, root)


def test_malformed_group_names_it_and_writes_nothing(tmp_path):
    src = tmp_path / "lift.hdf5"
    write_lift_hdf5(src, demos=2, length=4)
    with h5py.File(src, "a") as f:
        del f["data/demo_1/obs"]
        f["data/demo_1"].create_dataset("obs", data=np.zeros(4))
    root = tmp_path / "out"
    with pytest.raises(ValueError, match=r"data/demo_1: malformed group 'obs'"):
        convert(src, root)
    _assert_nothing_written(tmp_path, root)


def test_cli_reports_errors_with_status_2(tmp_path, capsys):
    src = tmp_path / "lift.hdf5"
    write_lift_hdf5(src, demos=1, length=4)
    with h5py.File(src, "a") as f:
        del f["data/demo_0/actions"]
    root = tmp_path / "out"
    assert main([str(src), "--root", str(root)]) == 2
    assert "data/demo_0: missing key 'actions'" in capsys.readouterr().err
    _assert_nothing_written(tmp_path, root)
