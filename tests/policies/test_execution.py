"""The paper's execution scheme (App. G) as policy options: the skipping arithmetic at chunk
boundaries, the window of executed actions, the measured-delay path of ``select_action``, and
exponential smoothing of the commanded target on SE(3)."""

from __future__ import annotations

import itertools

import pytest
import torch
from lerobot.configs.types import NormalizationMode

from lerobot_actionflow import geometry as g
from lerobot_actionflow.policies import execution
from lerobot_actionflow.policies.config_errors import PolicyConfigError
from lerobot_actionflow.schema import ACTION_KEY
from lerobot_actionflow.schema.tensors import action_to_pose, pose_to_action

from .test_chunk_conventions import N_OBS, _actionflow, _euclidean_flow


@pytest.mark.parametrize(
    ("delay_steps", "skipped"),
    [(0, 0), (1e-12, 0), (0.5, 1), (0.999, 1), (1, 1), (1.001, 2), (3, 3), (40, 40)],
)
def test_skipped_actions_are_those_already_due(delay_steps, skipped):
    assert execution.num_skipped(delay_steps) == skipped


@pytest.mark.parametrize(
    ("delay_s", "skipped"), [(0.0, 0), (0.0399, 1), (0.04, 1), (0.0401, 2), (0.08, 2), (0.12, 3), (0.2, 5)]
)
def test_delays_in_seconds_count_whole_control_periods(delay_s, skipped):
    options = execution.ExecutionOptions(delay_s=delay_s, control_period_s=0.04)
    assert execution.num_skipped(options.delay_in_steps()) == skipped


def test_fixed_steps_and_measured_seconds_add_up():
    options = execution.ExecutionOptions(delay_steps=1, delay_s=0.01, measure=True, control_period_s=0.05)
    assert options.delay_in_steps(0.09) == pytest.approx(3.0)
    assert execution.ExecutionOptions(delay_steps=2).delay_in_steps(5.0) == 2  # not measured
    with pytest.raises(ValueError, match="control step"):
        execution.num_skipped(-1)
    with pytest.raises(ValueError, match="control step"):
        execution.num_skipped(float("nan"))


@pytest.mark.parametrize(
    ("skipped", "window"),
    [(0, (0, 2)), (1, (1, 3)), (14, (14, 16)), (15, (15, 16)), (16, (15, 16)), (100, (15, 16))],
)
def test_execution_window_at_the_chunk_end(skipped, window):
    """m = 2 actions from the first one still due; past the chunk's end only its last action."""
    w = execution.execution_window(16, skipped, 2)
    assert (w.start, w.stop) == window


@pytest.mark.parametrize("make", [_actionflow, _euclidean_flow], ids=["actionflow", "euclidean_flow"])
def test_select_action_skips_the_measured_delay(make, monkeypatch):
    policy, batch, noise, _ = make()
    history = {
        k: v[:, :1].expand(-1, N_OBS, *v.shape[2:]).clone() for k, v in batch.items() if k != ACTION_KEY
    }
    chunk = policy.predict_action_chunk(history, noise=noise)
    policy.config.n_action_steps = 2
    policy.config.measure_inference_delay = True
    policy.config.control_period_s = 0.05
    policy.config.execution_delay_steps = 1
    policy.reset()
    # the chunk takes 0.07 s: 1 fixed + 1.4 measured = 2.4 steps, so actions 0..2 are past
    clock = itertools.chain([10.0, 10.07], itertools.count(20.0))
    monkeypatch.setattr(execution, "perf_counter", lambda: next(clock))
    step = {k: v[:, 0] for k, v in history.items()}
    executed = torch.stack([policy.select_action(step, noise=noise) for _ in range(2)], 1)
    torch.testing.assert_close(executed, chunk[:, 3:5])
    assert len(policy._queues[ACTION_KEY]) == 0


def _random_actions(n, gen, dtype=torch.float64):
    r = g.random_rotation(n, 2, generator=gen, dtype=dtype)
    p = torch.randn(n, 2, 3, generator=gen, dtype=dtype)
    return pose_to_action(r, p, torch.rand(n, 2, generator=gen, dtype=dtype))


def test_smoothing_stays_on_se3_and_alpha_one_is_the_identity():
    gen = torch.Generator().manual_seed(0)
    actions = _random_actions(50, gen, torch.float32)
    smoother = execution.TargetSmoother(0.3)
    out = torch.stack([smoother(a) for a in actions])
    r = action_to_pose(out)[0]
    ortho = (r.transpose(-1, -2) @ r - torch.eye(3)).abs().max()
    assert ortho < 1e-5 and (torch.det(r) - 1).abs().max() < 1e-5
    torch.testing.assert_close(out[0], actions[0])  # the first target passes through
    # the position and the gripper are plain exponential averages
    position_and_gripper = [0, 1, 2, 9]
    expected = actions[0, :, position_and_gripper]
    for a, o in zip(actions[1:], out[1:]):
        expected = 0.7 * expected + 0.3 * a[:, position_and_gripper]
        torch.testing.assert_close(o[:, position_and_gripper], expected)
    # the rotation moves 30 % of the way to the new target, along the geodesic
    r_prev, r_new = action_to_pose(out[-2])[0], action_to_pose(actions[-1])[0]
    torch.testing.assert_close(g.geodesic_distance(r_prev, r[-1]), 0.3 * g.geodesic_distance(r_prev, r_new))

    identity = execution.TargetSmoother(1.0)
    assert all(identity(a) is a for a in actions)
    smoother.reset()
    torch.testing.assert_close(smoother(actions[5]), actions[5])


def test_smoothing_is_equivariant():
    gen = torch.Generator().manual_seed(1)
    actions = _random_actions(20, gen)
    r_d, p_d = g.random_rotation(generator=gen, dtype=torch.float64), torch.randn(3, generator=gen).double()

    def moved(a):
        r, p, grip = action_to_pose(a)
        return pose_to_action(r_d @ r, (r_d @ p[..., None]).squeeze(-1) + p_d, grip)

    plain, transformed = execution.TargetSmoother(0.4), execution.TargetSmoother(0.4)
    for a in actions:
        torch.testing.assert_close(transformed(moved(a)), moved(plain(a)), atol=1e-9, rtol=0)


@pytest.mark.parametrize("make", [_actionflow, _euclidean_flow], ids=["actionflow", "euclidean_flow"])
def test_select_action_smooths_the_target(make):
    policy, batch, noise, _ = make()
    history = {
        k: v[:, :1].expand(-1, N_OBS, *v.shape[2:]).clone() for k, v in batch.items() if k != ACTION_KEY
    }
    chunk = policy.predict_action_chunk(history, noise=noise)
    policy.config.target_smoothing = 0.5  # on absolute poses: no action normalisation
    policy.config.normalization_mapping = {
        **policy.config.normalization_mapping,
        "ACTION": NormalizationMode.IDENTITY,
    }
    policy.config.validate_features()
    policy.reset()
    step = {k: v[:, 0] for k, v in history.items()}
    first, second = (policy.select_action(step, noise=noise) for _ in range(2))
    torch.testing.assert_close(first, chunk[:, 0])
    expected = execution.TargetSmoother(0.5)
    expected(chunk[:, 0])
    torch.testing.assert_close(second, expected(chunk[:, 1]))


def test_configs_refuse_unusable_execution_options():
    from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig

    from .actionflow.helpers import small_config

    with pytest.raises(PolicyConfigError, match="need `control_period_s`"):
        small_config(execution_delay_s=0.1)
    with pytest.raises(PolicyConfigError, match="need `control_period_s`"):
        EuclideanFlowConfig(measure_inference_delay=True)
    with pytest.raises(PolicyConfigError, match=r"`target_smoothing` must be in \(0, 1\]"):
        small_config(target_smoothing=0.0)
    with pytest.raises(PolicyConfigError, match="`execution_delay_steps` must be an integer >= 0"):
        small_config(execution_delay_steps=-1)
    small_config(execution_delay_s=0.1, control_period_s=0.04, target_smoothing=0.5)
    policy, *_ = _euclidean_flow()
    policy.config.target_smoothing = 0.5
    with pytest.raises(ValueError, match="normalization_mapping\\['ACTION'\\] = IDENTITY"):
        policy.config.validate_features()
    policy.config.normalization_mapping = {
        **policy.config.normalization_mapping,
        "ACTION": NormalizationMode.IDENTITY,
    }
    policy.config.validate_features()
