"""LeRobot's real-time chunking (``lerobot-rollout --inference.type=rtc``) for both policies: the
engine accepts them, the first ``inference_delay`` actions reproduce the leftover chunk, no
leftover changes nothing, the engine's one-step observations build the history, and ActionFlow
stays SE(3)-equivariant with RTC on; ``guide_to_previous_chunk`` does the same guidance inside
``select_action``."""

from __future__ import annotations

import pytest
import torch
from lerobot.configs import RTCAttentionSchedule
from lerobot.policies.rtc.configuration_rtc import RTCConfig
from lerobot.rollout.inference.rtc import _normalize_prev_actions_length, supports_rtc_inference

from lerobot_actionflow import geometry as g
from lerobot_actionflow.policies.config_errors import PolicyConfigError
from lerobot_actionflow.schema import ACTION_KEY
from lerobot_actionflow.schema.tensors import action_to_pose

from .actionflow.helpers import transform_batch
from .test_chunk_conventions import N_OBS, _actionflow, _euclidean_flow

POLICIES = pytest.mark.parametrize(
    "make", [_actionflow, _euclidean_flow], ids=["actionflow", "euclidean_flow"]
)


def _observations(batch):
    return {k: v for k, v in batch.items() if k != ACTION_KEY}


def _leftover(policy, batch, gen, length):
    """A previous chunk's unexecuted tail, as the engine gives it: one chunk, (T, A)."""
    other = {k: v + 0.05 * torch.randn(v.shape, generator=gen) for k, v in _observations(batch).items()}
    if "observation.poses" in other:  # keep unit quaternions
        poses = other["observation.poses"]
        other["observation.poses"] = torch.cat([poses[..., :3], batch["observation.poses"][..., 3:]], -1)
    return policy.predict_action_chunk(other)[0, :length]


@POLICIES
def test_the_rollout_engine_accepts_the_policy(make):
    policy, *_ = make()
    assert policy.supports_rtc()
    assert supports_rtc_inference(policy)


@POLICIES
@pytest.mark.parametrize("delay", [0, 1, 3])
def test_first_delay_actions_equal_the_leftover(make, delay):
    policy, batch, noise, chunk_len = make()
    obs = {k: v[:1] for k, v in _observations(batch).items()}
    noise = (
        noise[:1] if isinstance(noise, torch.Tensor) else type(noise)(*(n[:1] for n in vars(noise).values()))
    )
    gen = torch.Generator().manual_seed(7)
    leftover = _leftover(policy, obs, gen, chunk_len - 1)
    # the engine pads or cuts the leftover to its execution horizon with zero actions
    padded = _normalize_prev_actions_length(leftover, target_steps=chunk_len + 2)
    plain = policy.predict_action_chunk(obs, noise=noise)
    rtc = policy.predict_action_chunk(obs, noise=noise, inference_delay=delay, prev_chunk_left_over=padded)
    assert rtc.shape == plain.shape and torch.isfinite(rtc).all()
    torch.testing.assert_close(rtc[0, :delay], leftover[:delay], atol=1e-5, rtol=0)
    # guidance beyond the frozen prefix: the next action is pulled toward the leftover's
    assert (rtc[0, delay] - leftover[delay]).norm() < (plain[0, delay] - leftover[delay]).norm()


@POLICIES
def test_no_leftover_samples_as_without_rtc(make):
    policy, batch, noise, _ = make()
    obs = _observations(batch)
    plain = policy.predict_action_chunk(obs, noise=noise)
    assert torch.equal(plain, policy.predict_action_chunk(obs, noise=noise, inference_delay=2))
    assert torch.equal(
        plain, policy.predict_action_chunk(obs, noise=noise, inference_delay=0, prev_chunk_left_over=None)
    )
    # RTC switched off by lerobot-rollout's config: the leftover is ignored
    policy.config.rtc_config = RTCConfig(enabled=False)
    leftover = torch.zeros(2, 4, plain.shape[-1]) + plain[:, :4]
    assert torch.equal(
        plain, policy.predict_action_chunk(obs, noise=noise, inference_delay=2, prev_chunk_left_over=leftover)
    )


@POLICIES
def test_the_rtc_schedule_comes_from_the_rollout_config(make):
    """ZEROS: only the frozen prefix is pulled to the leftover; ONES: the whole execution
    horizon lands on it."""
    policy, batch, noise, chunk_len = make()
    obs = _observations(batch)
    leftover = _leftover(policy, obs, torch.Generator().manual_seed(8), chunk_len)
    kw = dict(noise=noise, inference_delay=1, prev_chunk_left_over=leftover)
    policy.config.rtc_config = RTCConfig(prefix_attention_schedule=RTCAttentionSchedule.ZEROS)
    zeros = policy.predict_action_chunk(obs, **kw)
    policy.config.rtc_config = RTCConfig(
        prefix_attention_schedule=RTCAttentionSchedule.ONES, execution_horizon=3
    )
    ones = policy.predict_action_chunk(obs, **kw)
    expected = leftover[None, :3].expand(2, -1, -1)
    torch.testing.assert_close(zeros[:, :1], expected[:, :1], atol=1e-5, rtol=0)
    torch.testing.assert_close(ones[:, :3], expected, atol=1e-4, rtol=0)
    assert (zeros[:, 1:3] - expected[:, 1:]).abs().amax() > 1e-2


@POLICIES
def test_one_step_observations_build_the_history(make):
    """The RTC engine sends only the latest observation: it joins the policy's history."""
    policy, batch, noise, _ = make()
    obs = _observations(batch)
    first = {k: v[:, 0] for k, v in obs.items()}
    second = {k: v[:, 1] for k, v in obs.items()}
    repeated = {k: v[:, :1].expand(-1, N_OBS, *v.shape[2:]) for k, v in obs.items()}
    policy.reset()
    a = policy.predict_action_chunk(first, noise=noise, inference_delay=0, prev_chunk_left_over=None)
    torch.testing.assert_close(a, policy.predict_action_chunk(repeated, noise=noise))
    # the same observation again (the RTC thread may be faster than the robot) is not appended
    policy.predict_action_chunk(first, noise=noise, inference_delay=0, prev_chunk_left_over=None)
    b = policy.predict_action_chunk(second, noise=noise, inference_delay=0, prev_chunk_left_over=None)
    torch.testing.assert_close(b, policy.predict_action_chunk(obs, noise=noise))


def test_bad_leftover_is_refused_by_name():
    policy, batch, *_ = _actionflow()
    obs = _observations(batch)
    with pytest.raises(ValueError, match=r"prev_chunk_left_over must hold actions \(\.\.\., 10\)"):
        policy.predict_action_chunk(obs, inference_delay=1, prev_chunk_left_over=torch.ones(4, 7))
    with pytest.raises(ValueError, match=r"prev_chunk_left_over must be \(T, A\) or \(B=2, T, A\)"):
        policy.predict_action_chunk(obs, inference_delay=1, prev_chunk_left_over=torch.ones(3, 4, 10))
    with pytest.raises(ValueError, match="prev_chunk_left_over contains non-finite"):
        policy.predict_action_chunk(
            obs, inference_delay=1, prev_chunk_left_over=torch.full((4, 10), torch.nan)
        )
    with pytest.raises(ValueError, match="inference_delay must be >= 0"):
        policy.predict_action_chunk(obs, inference_delay=-1, prev_chunk_left_over=torch.ones(4, 10))


def _equivariance_error(a, a_t, r_d, p_d):
    (r, p, grip), (r_t, p_t, grip_t) = action_to_pose(a), action_to_pose(a_t)
    err_p = (p_t - ((r_d @ p[..., None]).squeeze(-1) + p_d)).abs().max()
    return max((r_t - r_d @ r).abs().max().item(), err_p.item(), (grip_t - grip).abs().max().item())


def test_actionflow_with_rtc_is_equivariant():
    """Moving the scene and the leftover chunk together moves the guided chunk with them."""
    policy, batch, noise, _ = _actionflow()
    gen = torch.Generator().manual_seed(9)
    leftover = torch.stack(
        [_leftover(policy, {k: v[i : i + 1] for k, v in batch.items()}, gen, 6) for i in range(2)]
    )
    r_d, p_d = g.random_rotation(generator=gen), torch.randn(3, generator=gen)
    moved = transform_batch({**_observations(batch), ACTION_KEY: leftover}, r_d, p_d)
    kw = dict(noise=noise, inference_delay=2)
    a = policy.predict_action_chunk(_observations(batch), prev_chunk_left_over=leftover, **kw)
    a_t = policy.predict_action_chunk(_observations(moved), prev_chunk_left_over=moved[ACTION_KEY], **kw)
    assert _equivariance_error(a, a_t, r_d, p_d) <= 1e-4
    # control: the leftover not moved with the scene
    a_c = policy.predict_action_chunk(_observations(moved), prev_chunk_left_over=leftover, **kw)
    assert _equivariance_error(a, a_c, r_d, p_d) > 1e-2


def _guided(policy, m: int, delay: int):
    policy.config.n_action_steps = m
    policy.config.execution_delay_steps = delay
    policy.config.guide_to_previous_chunk = True
    policy.config.validate_execution()
    policy.reset()
    return policy


def _run(policy, steps, m, noise):
    """select_action ``m`` times on each observation step ``(B, ...)``: the executed ``(B, T, A)``."""
    return torch.stack([policy.select_action(s, noise=noise) for s in steps for _ in range(m)], 1)


@POLICIES
@pytest.mark.parametrize("delay", [0, 1])
def test_select_action_guides_each_chunk_toward_the_previous_one(make, delay):
    """``guide_to_previous_chunk``: the first chunk is the plain one; at the next boundary
    ``select_action`` samples ``predict_action_chunk(inference_delay=d, prev_chunk_left_over=the
    first chunk from the current step on)`` and executes it from the skipped ``d`` on."""
    policy, batch, noise, _ = make()
    m = 2
    policy = _guided(policy, m, delay)
    history = {k: v[:, :1].expand(-1, N_OBS, *v.shape[2:]).clone() for k, v in _observations(batch).items()}
    step = {k: v[:, 0] for k, v in history.items()}
    executed = _run(policy, [step, step], m, noise)
    first = policy.predict_action_chunk(history, noise=noise)
    leftover = first[:, delay + m :]
    second = policy.predict_action_chunk(
        history, noise=noise, inference_delay=delay, prev_chunk_left_over=leftover
    )
    torch.testing.assert_close(executed[:, :m], first[:, delay : delay + m])
    torch.testing.assert_close(executed[:, m:], second[:, delay : delay + m])
    # control: unguided, the same observation and noise give the first chunk again
    assert (second[:, delay : delay + m] - first[:, delay : delay + m]).abs().amax() > 1e-3


def test_guided_select_action_is_equivariant():
    """Moving the scene moves every executed action of a guided episode (two chunks, the second
    guided toward the first's leftover, which moved with it)."""
    policy, batch, noise, _ = _actionflow()
    m = 2
    policy = _guided(policy, m, delay=1)
    gen = torch.Generator().manual_seed(10)
    r_d, p_d = g.random_rotation(generator=gen), torch.randn(3, generator=gen)
    obs, moved = _observations(batch), _observations(transform_batch(_observations(batch), r_d, p_d))

    def steps(o):
        return [{k: v[:, i] for k, v in o.items()} for i in range(N_OBS)]

    a = _run(policy, steps(obs), m, noise)
    policy.reset()
    a_t = _run(policy, steps(moved), m, noise)
    assert _equivariance_error(a, a_t, r_d, p_d) <= 1e-4
    # control: the moved episode's first chunk guided toward the unmoved episode's leftover
    policy.reset()
    _run(policy, steps(obs), m, noise)
    unmoved = policy._previous_chunk
    policy.reset()
    policy._previous_chunk = unmoved
    a_c = _run(policy, steps(moved), m, noise)
    assert _equivariance_error(a, a_c, r_d, p_d) > 1e-2


def test_guidance_is_on_by_default_with_euler_and_refused_with_midpoint():
    from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig
    from lerobot_actionflow.policies.execution import guides_chunks

    from .actionflow.helpers import small_config

    assert guides_chunks(small_config()) and guides_chunks(EuclideanFlowConfig())
    assert not guides_chunks(small_config(solver="midpoint"))  # the default follows the solver
    assert not guides_chunks(small_config(guide_to_previous_chunk=False))
    with pytest.raises(PolicyConfigError, match="`guide_to_previous_chunk` steers Euler steps"):
        small_config(guide_to_previous_chunk=True, solver="midpoint")
    with pytest.raises(PolicyConfigError, match="`guide_to_previous_chunk` must be true, false or null"):
        small_config(guide_to_previous_chunk="yes")


@POLICIES
def test_select_action_guides_by_default(make):
    """A default config guides its second chunk; ``guide_to_previous_chunk=False`` does not."""
    policy, batch, noise, _ = make()
    step = {k: v[:, 0] for k, v in _observations(batch).items()}
    m = policy.config.n_action_steps
    guided = _run(policy.reset() or policy, [step, step], m, noise)
    policy.config.guide_to_previous_chunk = False
    policy.reset()
    plain = _run(policy, [step, step], m, noise)
    torch.testing.assert_close(guided[:, :m], plain[:, :m])  # the first chunk has no previous one
    assert (guided[:, m:] - plain[:, m:]).abs().amax() > 1e-3
