"""benchmarks/chunk_spread.py: chunk targets relative to the EEF are measured in the EEF frame,
so a rigid motion of a whole episode leaves them unchanged (the control moves the targets alone);
chunks never run past their episode; each action of a chunk is measured from the EEF of the
chunk's first frame, and a known offset and angle come back exactly."""

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import chunk_spread


def _episodes(rng, lengths):
    n = sum(lengths)
    episode = np.repeat(np.arange(len(lengths)), lengths)
    eef_r = Rotation.random(n, random_state=rng).as_matrix()
    act_r = Rotation.random(n, random_state=rng).as_matrix()
    return eef_r, rng.normal(size=(n, 3)), act_r, rng.normal(size=(n, 3)), episode


def test_a_rigid_motion_of_the_episode_leaves_the_offsets_unchanged_and_moving_the_targets_alone_does_not():
    rng = np.random.default_rng(0)
    eef_r, eef_p, act_r, act_p, episode = _episodes(rng, [12, 9])
    g_r, g_p = Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3)
    off, ang = chunk_spread.chunk_offsets(eef_r, eef_p, act_r, act_p, episode, horizon=4)
    moved = (g_r @ eef_r, eef_p @ g_r.T + g_p, g_r @ act_r, act_p @ g_r.T + g_p)
    off_g, ang_g = chunk_spread.chunk_offsets(*moved, episode, horizon=4)
    np.testing.assert_allclose(off_g, off, atol=1e-12)
    np.testing.assert_allclose(ang_g, ang, atol=1e-9)
    # Control: the same motion applied to the targets only changes both figures.
    targets_moved = (g_r @ act_r, act_p @ g_r.T + g_p)
    off_c, ang_c = chunk_spread.chunk_offsets(eef_r, eef_p, *targets_moved, episode, horizon=4)
    assert np.abs(off_c - off).max() > 1e-3 and np.abs(ang_c - ang).max() > 1e-3


def test_only_chunks_that_end_inside_their_episode_are_counted():
    rng = np.random.default_rng(1)
    off, ang = chunk_spread.chunk_offsets(*_episodes(rng, [5, 2, 7]), horizon=3)
    # (5 - 3 + 1) + 0 + (7 - 3 + 1) chunks of 3 actions each.
    assert off.shape == (8 * 3, 3) and ang.shape == (8 * 3,)


def test_every_action_of_a_chunk_is_measured_from_the_eef_of_the_chunks_first_frame():
    yaw90 = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    # Frame 0's EEF is yawed 90 degrees at the origin; frame 1's EEF is elsewhere and turned.
    eef_r = np.stack([yaw90, Rotation.from_euler("x", 50, degrees=True).as_matrix()])
    eef_p = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1]])
    # Both targets lie 0.1 m along world y (the frame-0 EEF's x), 30 degrees about x beyond it.
    act_r = np.stack([yaw90 @ Rotation.from_euler("x", 30, degrees=True).as_matrix()] * 2)
    act_p = np.array([[0.0, 0.1, 0.0]] * 2)
    off, ang = chunk_spread.chunk_offsets(eef_r, eef_p, act_r, act_p, np.zeros(2), horizon=2)
    np.testing.assert_allclose(off, [[0.1, 0.0, 0.0]] * 2, atol=1e-12)
    np.testing.assert_allclose(np.degrees(ang), [30.0, 30.0], atol=1e-9)


def test_mismatched_lengths_and_a_bad_horizon_are_named():
    eef_r, eef_p, act_r, act_p, episode = _episodes(np.random.default_rng(2), [4])
    with pytest.raises(ValueError, match="act_p has 3 frames, episode has 4"):
        chunk_spread.chunk_offsets(eef_r, eef_p, act_r, act_p[:3], episode, horizon=2)
    with pytest.raises(ValueError, match="horizon must be >= 1"):
        chunk_spread.chunk_offsets(eef_r, eef_p, act_r, act_p, episode, horizon=0)
