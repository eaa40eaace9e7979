"""Smoothness figures on hand-made target trajectories."""

import numpy as np
import pytest

from lerobot_actionflow.evaluation.smoothness import (
    jerk,
    position_jumps,
    rotation_jumps,
    smoothness_figures,
)
from lerobot_actionflow.rotations import matrix_to_rotation_6d, yaw_matrix
from lerobot_actionflow.schema import ACTION_DIM


def trajectory(positions, yaws=None) -> np.ndarray:
    """Targets ``(T, ACTION_DIM)`` at ``positions`` ``(T, 3)``, rotated by ``yaws`` about z."""
    p = np.asarray(positions, dtype=np.float64)
    yaws = np.zeros(len(p)) if yaws is None else np.asarray(yaws, dtype=np.float64)
    t = np.zeros((len(p), ACTION_DIM))
    t[:, :3] = p
    t[:, 3:9] = matrix_to_rotation_6d(yaw_matrix(yaws))
    return t


def test_a_still_target_has_no_jump_and_no_jerk():
    figs = smoothness_figures(trajectory(np.tile([0.1, 0.2, 0.9], (10, 1))))
    assert figs == {"max_position_jump_m": 0.0, "max_rotation_jump_rad": 0.0, "jerk_m2": 0.0}


def test_constant_and_uniformly_accelerated_motions_have_no_jerk():
    t = np.arange(12.0)
    assert jerk(trajectory(np.stack([0.01 * t, 0 * t, 0 * t], 1))) == pytest.approx(0.0, abs=1e-20)
    assert jerk(trajectory(np.stack([0.001 * t**2, 0 * t, 0 * t], 1))) == pytest.approx(0.0, abs=1e-18)
    assert position_jumps(trajectory(np.stack([0.01 * t, 0 * t, 0 * t], 1))).max() == pytest.approx(0.01)


def test_a_step_in_the_target_is_its_largest_jump_and_shows_as_jerk():
    p = np.zeros((10, 3))
    p[5:, 1] = 0.1  # a 10 cm jump between steps 4 and 5
    figs = smoothness_figures(trajectory(p))
    assert figs["max_position_jump_m"] == pytest.approx(0.1)
    # third differences of a unit step: 1, -2, 1 (times 0.1) over 7 windows
    assert figs["jerk_m2"] == pytest.approx(0.01 * (1 + 4 + 1) / 7)


def test_rotation_jumps_are_geodesic_angles():
    yaws = [0.0, 0.1, 0.2, 0.2, 2.0]
    jumps = rotation_jumps(trajectory(np.zeros((5, 3)), yaws))
    np.testing.assert_allclose(jumps, [0.1, 0.1, 0.0, 1.8], atol=1e-9)
    # 2 pi - 0.1 about z is 0.1 away from the identity along the geodesic, not 6.18
    assert rotation_jumps(trajectory(np.zeros((2, 3)), [0.0, 2 * np.pi - 0.1]))[0] == pytest.approx(0.1)


def test_short_trajectories_measure_nothing():
    assert smoothness_figures(np.zeros((0, ACTION_DIM)))["max_position_jump_m"] == 0.0
    assert jerk(trajectory(np.random.default_rng(0).normal(size=(3, 3)))) == 0.0


def test_wrong_shape_is_refused():
    with pytest.raises(ValueError, match=f"\\(T, {ACTION_DIM}\\)"):
        smoothness_figures(np.zeros((5, 7)))


def test_sweep_tables_list_every_cell_and_the_skipped_ones():
    from lerobot_actionflow.evaluation.latency_sweep import checkpoint_label, format_tables

    ckpt = "out/af/train/checkpoints/last/pretrained_model"
    assert checkpoint_label(ckpt) == "af/train/last"
    base = {"checkpoint": ckpt, "policy": "actionflow", "inference_steps": 4}
    figures = {"n_episodes": 10, "held_steps_per_chunk": 4.0, "mean_max_position_jump_m": 0.05,
               "mean_max_rotation_jump_rad": np.pi / 6, "mean_jerk_m2": 2e-6}  # fmt: skip
    rows = [
        {**base, "mode": "plain", "latency_ms": 0.0, "pc_success": 80.0, **figures},
        {**base, "mode": "plain", "latency_ms": 200.0, "pc_success": 40.0, **figures},
        {**base, "policy": "diffusion", "mode": "rtc", "latency_ms": 0.0, "skipped": "no RTC"},
    ]
    table = format_tables(rows)
    assert "| af/train/last (actionflow K/IS=4) plain | 80 (10) | 40 (10) |" in table
    assert "| 200 ms | 4.0 | 50.0 | 30.0 | 2.00 |" in table
    assert "Skipped: af/train/last (diffusion K/IS=4) rtc: no RTC" in table
