"""MugHang: what its success check accepts and refuses, and where each variant puts the hanger."""

from __future__ import annotations

import math

import numpy as np
import pytest
from env_success_states import IDENTITY, mug_hang

from lerobot_actionflow.envs import mug_hang as mh
from lerobot_actionflow.experts import frames as fr
from lerobot_actionflow.experts.pose import Pose

D0, MOVED = "lerobot_actionflow/MugHang_D0-v0", "lerobot_actionflow/MugHang_Moved-v0"


def _hold(env, steps: int) -> bool:
    """Step with the arm holding still, open; whether any step was a success."""
    pos, mat = env.eef_pose()
    hold = np.concatenate([pos, mat[:, 0], mat[:, 1], [-1.0]]).astype(np.float32)
    return any(env.step(hold)[4]["is_success"] for _ in range(steps))


def test_a_settled_hanging_mug_succeeds_and_only_after_settling(make_cached):
    env = make_cached(MOVED).unwrapped
    env.reset(seed=4)
    rs = env.robosuite_env
    mug_hang(env, steps=0)  # threaded, 2 mm over the peg, not simulated yet
    assert rs.peg_through_handle() and not env.is_success()  # still steps are counted, none yet
    assert _hold(env, 60) and env.is_success()
    assert rs.settled_steps >= mh.SETTLED_STEPS and rs.hanging()
    # Teleported beside the peg (handle 4 cm off its axis, same height): no longer threaded.
    mug = env.get_observation()["poses"][1].astype(np.float64)
    _, u = rs.peg_frame()
    side = np.cross(u, [0.0, 0.0, 1.0])
    env.set_body_pose("mug_root", mug[:3] + 0.04 * side / np.linalg.norm(side), mug[3:])
    assert not rs.peg_through_handle() and not env.is_success()


def test_a_mug_on_the_table_under_the_peg_fails(make_cached):
    """Standing on the table right under the peg, still: touching the table, not threaded."""
    env = make_cached(D0).unwrapped
    env.reset(seed=1)
    root, u = env.robosuite_env.peg_frame()
    below = root + 0.07 * u
    env.set_body_pose("mug_root", [below[0] - 0.06, below[1], mh.MUG_HALF_HEIGHT + 0.8005], IDENTITY)
    assert not _hold(env, 10)
    assert not env.robosuite_env.hanging()


def _layouts(env, seeds):
    """Hanger and mug ``(x, y, yaw)`` per seed; checks that the peg rises at its angle and the
    mug stands upright in every layout (a mirrored one too)."""
    obs = []
    for s in seeds:
        obs.append(env.reset(seed=s)[0]["poses"].astype(np.float64))
        rs = env.unwrapped.robosuite_env
        assert rs.peg_frame()[1][2] == pytest.approx(math.sin(mh.PEG_ANGLE), abs=1e-6)
        assert rs.handle_frame()[1][2, 2] == pytest.approx(1.0, abs=1e-3)
    hanger = np.array([[*o[2, :2], fr.yaw_of(Pose.from_pose7(o[2]).r)] for o in obs])
    mug = np.array([[*o[1, :2], fr.yaw_of(Pose.from_pose7(o[1]).r)] for o in obs])
    return hanger, mug


def test_d0_keeps_the_hanger_in_place_and_moved_puts_it_on_either_side_turned(make_cached):
    seeds = range(10)
    h0, m0 = _layouts(make_cached(D0), seeds)
    h1, m1 = _layouts(make_cached(MOVED), seeds)
    # D0: one hanger pose (the peg pointing at the robot, -x); the mug varies within its ranges.
    np.testing.assert_allclose(h0, np.broadcast_to(h0[0], h0.shape), atol=1e-6)
    assert abs(fr.wrap(h0[0, 2] - math.pi)) < 1e-6 and abs(h0[0, 1]) < 1e-6
    for m in (m0, m1):
        assert np.ptp(m[:, 0]) > 0.02 and np.ptp(m[:, 1]) > 0.03 and np.ptp(m[:, 2]) > math.radians(10)
        assert (m[:, 0] >= -0.12 - 1e-6).all() and (m[:, 0] <= -0.04 + 1e-6).all()
        assert (np.abs(m[:, 1]) <= 0.06 + 1e-6).all() and (np.abs(m[:, 2]) <= math.radians(20) + 1e-6).all()
    # Moved: the hanger 0.20-0.25 m to the left or the right (both occur), turned by up to 35 deg.
    assert (np.abs(h1[:, 1]) >= 0.20 - 1e-6).all() and (np.abs(h1[:, 1]) <= 0.25 + 1e-6).all()
    assert (h1[:, 1] > 0).any() and (h1[:, 1] < 0).any()
    turn = np.array([fr.wrap(y - math.pi) for y in h1[:, 2]])
    assert (np.abs(turn) <= math.radians(35) + 1e-6).all() and np.ptp(turn) > math.radians(20)
