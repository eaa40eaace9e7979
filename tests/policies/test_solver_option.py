"""The ``solver`` option of both policies: network calls per chunk, the inference-step sweep's
call counting, RTC's refusal of the midpoint solver, and ActionFlow's equivariance with it."""

from __future__ import annotations

import pytest
import torch

from lerobot_actionflow.evaluation.sweep import set_inference_steps
from lerobot_actionflow.flow import se3 as se3_flow
from lerobot_actionflow.geometry import so3
from lerobot_actionflow.schema import ACTION_KEY

from .actionflow.helpers import random_batch
from .actionflow.test_equivariance import _equivariance_error, _policy, _random_transform, _sample_twice
from .test_chunk_conventions import _actionflow, _euclidean_flow


def _count_calls(policy) -> list:
    calls = []
    net = policy.network if hasattr(policy, "network") else policy.velocity_net
    name = "velocity" if hasattr(policy, "network") else "forward"
    original = getattr(net, name)
    setattr(net, name, lambda *a, **k: calls.append(1) or original(*a, **k))
    return calls


@pytest.mark.parametrize("make", [_actionflow, _euclidean_flow], ids=["actionflow", "euclidean_flow"])
def test_midpoint_spends_two_calls_per_step_and_the_sweep_counts_calls(make):
    policy, batch, noise, _ = make()
    policy.config.solver = "midpoint"
    assert set_inference_steps(policy, 6) == f"midpoint-{policy.config.time_spacing}"
    assert policy.config.num_inference_steps == 3
    calls = _count_calls(policy)
    policy.predict_action_chunk(batch, noise=noise)
    assert len(calls) == 6
    with pytest.raises(ValueError, match=r"5 inference steps .* solver='midpoint'.* multiple of 2"):
        set_inference_steps(policy, 5)


@pytest.mark.parametrize("make", [_actionflow, _euclidean_flow], ids=["actionflow", "euclidean_flow"])
def test_rtc_refuses_the_midpoint_solver(make):
    policy, batch, noise, _ = make()
    leftover = policy.predict_action_chunk(batch, noise=noise)[0, :4]
    policy.config.solver = "midpoint"
    with pytest.raises(ValueError, match=r"solver is 'midpoint'.*--policy.solver=euler"):
        policy.predict_action_chunk(batch, noise=noise, inference_delay=1, prev_chunk_left_over=leftover)


def test_the_solver_option_is_validated():
    from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig
    from lerobot_actionflow.policies.config_errors import PolicyConfigError

    with pytest.raises(PolicyConfigError, match=r"`solver` must be one of \('euler', 'midpoint'\)"):
        ActionflowConfig(device="cpu", solver="heun")


def _midpoint_setup(seed):
    policy = _policy(torch.float32, solver="midpoint", translation_velocity_frame="eef")
    gen = torch.Generator().manual_seed(seed)
    batch = {k: v for k, v in random_batch(policy.config, 3, gen).items() if k != ACTION_KEY}
    noise = se3_flow.draw_local_noise(3, policy.config.horizon, 0.1, generator=gen)
    return policy, batch, noise, *_random_transform(gen, torch.float32)


def test_midpoint_sampled_actions_are_equivariant():
    policy, batch, noise, r_d, p_d = _midpoint_setup(10)
    pose, pose_t = _sample_twice(policy, batch, noise, r_d, p_d)
    assert _equivariance_error(pose, pose_t, r_d, p_d) <= 1e-4


def test_midpoint_equivariance_check_fails_with_a_world_frame_half_step(monkeypatch):
    """Control: reading the half-step translation velocity as a world vector (not rotating it by
    the half pose) breaks equivariance, and the same check catches it."""

    def world_frame_step(x, velocity, v, dt):
        half = se3_flow.euler_step(x, v, 0.5 * dt)
        w = velocity(half)
        return se3_flow.PoseChunk(x.r @ so3.exp(dt * w.r), x.p + dt * w.p, x.g + dt * w.g)

    monkeypatch.setattr(se3_flow, "midpoint_step", world_frame_step)
    policy, batch, noise, r_d, p_d = _midpoint_setup(10)
    pose, pose_t = _sample_twice(policy, batch, noise, r_d, p_d)
    assert _equivariance_error(pose, pose_t, r_d, p_d) > 1e-2
