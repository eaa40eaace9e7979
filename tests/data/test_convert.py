"""``actionflow-convert``: robomimic HDF5 -> LeRobotDataset: values, error handling, and the
conventions checked against robosuite's simulator and OSC controller."""

from __future__ import annotations

import collections
import json
import subprocess

import h5py
import numpy as np
import pytest
import torch

from lerobot_actionflow import geometry as g
from lerobot_actionflow import rotations as rot
from lerobot_actionflow.data import schema_arrays
from lerobot_actionflow.data.convert import convert, main
from lerobot_actionflow.data.features import default_repo_id
from lerobot_actionflow.schema import ACTION_KEY, POSES_KEY, STATE_KEY
from tests.data.conftest import BIN, cli_env
from tests.data.robomimic_hdf5 import write_lift_hdf5, write_robomimic_hdf5


def _load(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(default_repo_id("Lift"), root=root)


def _episode(ds, e):
    idx = [i for i in range(len(ds)) if int(ds[i]["episode_index"]) == e]
    return {k: torch.stack([ds[i][k] for i in idx]).double() for k in (POSES_KEY, STATE_KEY, ACTION_KEY)}


def _rot(q_xyzw):
    return g.quaternion_to_matrix(g.xyzw_to_wxyz(torch.as_tensor(q_xyzw, dtype=torch.float64)))


def test_round_trip_converts_quaternions_keeps_positions_and_integrates_deltas(tmp_path):
    """Values through the CLI on random data. The hand-to-site rotation's value is checked
    against the simulator below; here only that it is one fixed rotation."""
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
    hand_to_eef = []
    for e in range(2):
        w = {k: torch.as_tensor(v, dtype=torch.float64) for k, v in written[f"demo_{e}"].items()}
        ep = _episode(ds, e)
        poses = ep[POSES_KEY]
        # Positions are kept.
        torch.testing.assert_close(poses[:, 0, :3], w["robot0_eef_pos"], atol=1e-6, rtol=0)
        torch.testing.assert_close(poses[:, 1, :3], w["cube_pos"], atol=1e-6, rtol=0)
        # Object quaternion: xyzw -> wxyz (same rotation; w >= 0 sign convention).
        q_cube = poses[:, 1, 3:]
        q_ref = g.xyzw_to_wxyz(w["cube_quat"])
        q_ref = q_ref * torch.sign(q_ref[:, :1])
        torch.testing.assert_close(q_cube, q_ref, atol=1e-5, rtol=0)
        # EEF: the state's rotation is the pose's, and the hand quaternion turned by a fixed rotation.
        r_eef = g.quaternion_to_matrix(poses[:, 0, 3:])
        torch.testing.assert_close(ep[STATE_KEY][:, 3:9], g.matrix_to_rotation_6d(r_eef), atol=1e-5, rtol=0)
        hand_to_eef.append(_rot(w["robot0_eef_quat"]).transpose(-1, -2) @ r_eef)
        torch.testing.assert_close(ep[STATE_KEY][:, 9:], w["robot0_gripper_qpos"], atol=1e-6, rtol=0)
        # Delta actions -> absolute targets with robomimic's scaling (0.05 m, 0.5 rad), clipped to [-1, 1].
        a = w["actions"].clamp(-1, 1)
        p_tgt, r_tgt = w["robot0_eef_pos"] + 0.05 * a[:, :3], g.exp(0.5 * a[:, 3:6]) @ r_eef
        torch.testing.assert_close(ep[ACTION_KEY][:, :3], p_tgt, atol=1e-6, rtol=0)
        torch.testing.assert_close(ep[ACTION_KEY][:, 3:9], g.matrix_to_rotation_6d(r_tgt), atol=1e-5, rtol=0)
        torch.testing.assert_close(ep[ACTION_KEY][:, 9], w["actions"][:, 6], atol=0, rtol=0)
    hand_to_eef = torch.cat(hand_to_eef)
    torch.testing.assert_close(hand_to_eef, hand_to_eef[:1].expand_as(hand_to_eef), atol=1e-5, rtol=0)


def test_absolute_controller_actions_are_copied(tmp_path):
    src = tmp_path / "lift.hdf5"
    written = write_lift_hdf5(src, demos=1, length=4, delta=False)
    root = tmp_path / "out"
    meta = convert(src, root)
    assert meta["action_mode"] == "absolute"
    ep = _episode(_load(root), 0)
    a = torch.as_tensor(written["demo_0"]["actions"])
    torch.testing.assert_close(ep[ACTION_KEY][:, :3], a[:, :3], atol=1e-6, rtol=0)
    torch.testing.assert_close(
        ep[ACTION_KEY][:, 3:9], g.matrix_to_rotation_6d(g.exp(a[:, 3:6])), atol=1e-5, rtol=0
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


def test_zero_quaternion_names_it_and_writes_nothing(tmp_path):
    src = tmp_path / "lift.hdf5"
    write_lift_hdf5(src, demos=2, length=4)
    with h5py.File(src, "a") as f:
        f["data/demo_1/obs/cube_quat"][2] = 0.0
    root = tmp_path / "out"
    with pytest.raises(ValueError, match=r"data/demo_1/obs/cube_quat: zero quaternions .*at frame 2"):
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


def test_absolute_actions_in_the_robot_base_frame_are_refused(tmp_path):
    src = tmp_path / "lift.hdf5"
    write_lift_hdf5(src, demos=1, length=4, delta=False)
    with h5py.File(src, "a") as f:
        args = json.loads(f["data"].attrs["env_args"])
        cc = args["env_kwargs"]["controller_configs"]
        del cc["control_delta"]
        cc.update(input_type="absolute", input_ref_frame="base")  # robosuite >= 1.5 keys
        f["data"].attrs["env_args"] = json.dumps(args)
    root = tmp_path / "out"
    with pytest.raises(ValueError, match=r"'base' frame .* --actions next_pose"):
        convert(src, root)
    _assert_nothing_written(tmp_path, root)


# ------------------------------------------------------------------ against the simulator
#: Largest difference accepted between a converted value and the simulator's (metres, and
#: rot6d entries, i.e. about radians): float32 storage of values near 1 m is exact to 1e-7.
SIM_ATOL = 1e-5
#: Arm actions of the recorded rollouts (deltas; components beyond [-1, 1] are clipped by the
#: controller). The absolute rollout moves and turns the grip site by as much.
ARM_ACTIONS = np.array(
    [
        [0.3, -0.2, 0.1, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.8, -0.5, 0.3],
        [-1.4, 0.6, -0.3, -0.2, 1.3, -0.9],
        [0.5, 0.9, 0.2, 1.0, 0.4, -1.2],
        [0.2, -0.7, 0.6, -0.9, -0.3, 0.7],
    ]
)


#: What robomimic records of a Lift rollout, besides actions and states.
OBS_KEYS = ("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos", "cube_pos", "cube_quat")


def _controller_config(input_type: str, ref_frame: str) -> dict:
    """robosuite's BASIC composite config for one Panda, its OSC_POSE arm set as asked."""
    from lerobot_actionflow.envs.controller import absolute_pose_controller_config

    cfg = absolute_pose_controller_config()  # BASIC, right arm only
    cfg["body_parts"]["right"].update(input_type=input_type, input_ref_frame=ref_frame)
    return cfg


def _record_lift(path, input_type: str, ref_frame: str) -> dict[str, np.ndarray]:
    """Drive robosuite's Lift with its own OSC_POSE controller and write what robomimic records
    (``robot0_eef_pos/quat``, ``robot0_gripper_qpos``, ``cube_pos/quat``, actions, states) to
    ``path`` in robomimic's layout. Returns, per step, what MuJoCo and the controller hold: the
    grip site pose when the obs were read, the cube body pose, and the controller's goal (in the
    world frame) after the action.

    robosuite returns observations read before the last physics substep's integration, one
    substep (2 ms) behind the state the controller reads at its next ``set_goal``. The recording
    refreshes them (``sim.forward``) so that the comparison can be exact; robomimic's own files
    carry that lag (up to 1.3 mm and 0.004 rad per step in this rollout), which no converter
    can remove.
    """
    import robosuite

    cfg = _controller_config(input_type, ref_frame)
    env = robosuite.make(
        "Lift", robots="Panda", controller_configs=cfg, has_renderer=False, has_offscreen_renderer=False,
        use_camera_obs=False, control_freq=20, seed=0,
    )  # fmt: skip
    rec = collections.defaultdict(list)
    try:
        obs = env.reset()
        robot, d = env.robots[0], env.sim.data
        arm = robot.composite_controller.part_controllers["right"]
        assert (arm.input_type, arm.input_ref_frame) == (input_type, ref_frame)
        assert arm._goal_update_mode == "achieved"  # goals from the pose read at set_goal
        site = env.sim.model.site_name2id(robot.gripper["right"].important_sites["grip_site"])
        for t, arm_action in enumerate(ARM_ACTIONS):
            site_p, site_r = d.site_xpos[site].copy(), d.site_xmat[site].reshape(3, 3).copy()
            if input_type == "absolute":  # the site pose moved and turned by the same amounts
                r_goal = rot.axis_angle_to_matrix(0.4 * arm_action[3:]) @ site_r
                arm_action = np.r_[site_p + 0.05 * arm_action[:3], rot.matrix_to_axis_angle(r_goal)]
            action = np.r_[arm_action, 1.0 if t % 2 else -1.0]
            for k in OBS_KEYS:
                rec[k].append(np.array(obs[k]))
            rec["actions"].append(action)
            rec["states"].append(env.sim.get_state().flatten())
            rec["site_pos"].append(site_p)
            rec["site_mat"].append(site_r)
            rec["cube_body"].append(np.r_[d.body_xpos[env.cube_body_id], d.body_xquat[env.cube_body_id]])
            env.step(action)
            goal_p, goal_r = arm.goal_pos, arm.goal_ori
            if ref_frame == "base":  # the controller's frame -> world, as its run_controller does
                goal_p, goal_r = arm.origin_pos + arm.origin_ori @ goal_p, arm.origin_ori @ goal_r
            rec["goal_pos"].append(np.array(goal_p))
            rec["goal_mat"].append(np.array(goal_r))
            env.sim.forward()
            obs = env._get_observations(force_update=True)
    finally:
        env.close()
    rec = {k: np.stack(v) for k, v in rec.items()}
    env_kwargs = {"robots": "Panda", "controller_configs": cfg, "control_freq": 20}
    env_args = {"env_name": "Lift", "env_type": 1, "env_kwargs": env_kwargs}
    write_robomimic_hdf5(path, env_args, [{k: rec[k] for k in (*OBS_KEYS, "actions", "states")}])
    return rec


def _errors_against_simulator(ep: dict[str, torch.Tensor], rec: dict[str, np.ndarray]) -> dict[str, float]:
    """Largest differences between a converted episode and the simulator's values."""
    sim = {k: torch.as_tensor(v, dtype=torch.float64) for k, v in rec.items()}
    poses, state, action = ep[POSES_KEY], ep[STATE_KEY], ep[ACTION_KEY]
    q_cube = sim["cube_body"][:, 3:] * torch.sign(sim["cube_body"][:, 3:4])

    def err(a, b):
        return float((a - b).abs().max())

    return {
        "eef_pos": max(err(poses[:, 0, :3], sim["site_pos"]), err(state[:, :3], sim["site_pos"])),
        "eef_rot": max(
            err(g.quaternion_to_matrix(poses[:, 0, 3:]), sim["site_mat"]),
            err(state[:, 3:9], g.matrix_to_rotation_6d(sim["site_mat"])),
        ),
        "cube": max(err(poses[:, 1, :3], sim["cube_body"][:, :3]), err(poses[:, 1, 3:], q_cube)),
        "gripper_qpos": err(state[:, 9:], sim["robot0_gripper_qpos"]),
        "target_pos": err(action[:, :3], sim["goal_pos"]),
        "target_rot": err(action[:, 3:9], g.matrix_to_rotation_6d(sim["goal_mat"])),
        "gripper_cmd": err(action[:, 9], sim["actions"][:, 6]),
    }


@pytest.mark.parametrize(
    "input_type, ref_frame",
    [("delta", "base"), ("delta", "world"), ("absolute", "world")],
    ids=["delta-base (robosuite 1.5 default)", "delta-world (robomimic)", "absolute-world (ours)"],
)
def test_conversion_matches_the_simulator_and_its_controller(tmp_path, monkeypatch, input_type, ref_frame):
    """Converted EEF poses equal MuJoCo's grip site pose, object poses the cube body's, and
    converted actions the goals robosuite's own OSC_POSE controller set from the recorded actions
    (``auto`` reads the mode from the controller config); to :data:`SIM_ATOL`. Controls: a wrong
    hand-to-site rotation (identity, or its transpose) must break the comparison."""
    src = tmp_path / "lift.hdf5"
    rec = _record_lift(src, input_type, ref_frame)
    meta = convert(src, tmp_path / "out")
    assert meta["action_mode"] == input_type
    errors = _errors_against_simulator(_episode(_load(tmp_path / "out"), 0), rec)
    assert max(errors.values()) < SIM_ATOL, errors
    if input_type != "delta" or ref_frame != "base":
        return
    for name, wrong in (("identity", np.eye(3)), ("transpose", schema_arrays.R_HAND_TO_SITE.T)):
        monkeypatch.setattr(schema_arrays, "R_HAND_TO_SITE", wrong)
        convert(src, tmp_path / name)
        bad = _errors_against_simulator(_episode(_load(tmp_path / name), 0), rec)
        assert bad["eef_rot"] > 0.5 and bad["target_rot"] > 0.5, (name, bad)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize(
    "key", ["obs/robot0_eef_pos", "obs/robot0_eef_quat", "obs/cube_pos", "obs/robot0_gripper_qpos", "actions"]
)
def test_non_finite_input_names_file_demo_key_and_frame_and_writes_nothing(tmp_path, key, value):
    src = tmp_path / "lift.hdf5"
    write_lift_hdf5(src, demos=2, length=5)
    with h5py.File(src, "a") as f:
        d = f[f"data/demo_1/{key}"]
        row = d[3]
        row[-1] = value
        d[3] = row
    root = tmp_path / "out"
    with pytest.raises(ValueError, match=rf"{src}: data/demo_1/{key}: .*frame 3") as e:
        convert(src, root)
    assert "NaN/inf" in str(e.value) or "degenerate" in str(e.value)
    _assert_nothing_written(tmp_path, root)


def test_position_overflowing_float32_is_refused(tmp_path):
    src = tmp_path / "lift.hdf5"
    write_lift_hdf5(src, demos=1, length=5)
    with h5py.File(src, "a") as f:
        f["data/demo_0/obs/cube_pos"][1] = [1e39, 0.0, 0.0]  # finite in float64, inf in float32
    root = tmp_path / "out"
    with pytest.raises(ValueError, match=rf"{src}: data/demo_0: output .* non-finite .*frame 1"):
        convert(src, root)
    _assert_nothing_written(tmp_path, root)


def test_directory_input_is_named_a_directory(tmp_path):
    (tmp_path / "in.hdf5").mkdir()
    with pytest.raises(ValueError, match="is a directory"):
        convert(tmp_path / "in.hdf5", tmp_path / "out")
