"""ActionFlow's defining property: an SE(3)-invariant velocity field, hence SE(3)-equivariant
action generation (App. C). Checked with random weights and after training, and shown to
fail when equivariance is deliberately broken."""

import pytest
import torch

from lerobot_actionflow import geometry as g
from lerobot_actionflow.flow import se3 as se3_flow
from lerobot_actionflow.nn import PoseAdaptation
from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
from lerobot_actionflow.schema.tensors import action_to_pose

from .helpers import random_batch, small_config, transform_batch

TOL_V = {torch.float32: 1e-5, torch.float64: 1e-9}


def _policy(dtype, seed=0, **kw):
    torch.manual_seed(seed)
    return ActionflowPolicy(small_config(**kw)).to(dtype).eval()


def _random_transform(gen, dtype, translation=1.0):
    return g.random_rotation(generator=gen, dtype=dtype), translation * torch.randn(
        3, generator=gen, dtype=dtype
    )


def _velocities(policy, batch, t):
    """Local velocities the network predicts at the (noisy) action poses of the batch."""
    obs = policy._observation_tokens(policy.check_observation(batch))
    return policy.network(obs, se3_flow.PoseChunk(*action_to_pose(batch["action"])), t)


def _check_invariance(policy, dtype, gen):
    batch = random_batch(policy.config, 3, gen, dtype)
    t = torch.rand(3, generator=gen, dtype=dtype)
    r_d, p_d = _random_transform(gen, dtype)
    with torch.no_grad():
        v = _velocities(policy, batch, t)
        v_t = _velocities(policy, transform_batch(batch, r_d, p_d), t)
    errs = [(a - b).abs().max().item() for a, b in zip(v, v_t)]
    scale = max(a.abs().max().item() for a in v)
    assert scale > 1e-3, "degenerate network output"
    return max(errs)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("frame", ["eef", "world"])
def test_velocity_field_is_invariant_with_random_weights(dtype, frame):
    """With frame='world' no pose is re-expressed: invariance then rests on IPA alone."""
    squash = frame == "eef"
    policy = _policy(dtype, adaptation_frame=frame, squash_translations=squash, images=("wrist",))
    gen = torch.Generator().manual_seed(1)
    assert _check_invariance(policy, dtype, gen) <= TOL_V[dtype]


@pytest.mark.parametrize("frame", ["eef", "world"])
def test_velocity_field_is_invariant_after_training(frame):
    policy = _policy(torch.float32, adaptation_frame=frame, squash_translations=frame == "eef").train()
    gen = torch.Generator().manual_seed(2)
    opt = torch.optim.Adam(policy.parameters(), lr=3e-3)
    for _ in range(20):
        loss, _ = policy.forward(random_batch(policy.config, 16, gen))
        opt.zero_grad()
        loss.backward()
        opt.step()
    policy.eval()
    for dtype in (torch.float32, torch.float64):
        assert _check_invariance(policy.to(dtype), dtype, gen) <= TOL_V[dtype]


def _sample_twice(policy, batch, noise, r_d, p_d):
    a = policy.predict_action_chunk(batch, noise=noise)
    a_t = policy.predict_action_chunk(transform_batch(batch, r_d, p_d), noise=noise)
    return action_to_pose(a), action_to_pose(a_t)


def _equivariance_error(pose, pose_t, r_d, p_d):
    (r, p, gr), (r_t, p_t, gr_t) = pose, pose_t
    err_r = (r_t - r_d @ r).abs().max()
    err_p = (p_t - ((r_d @ p[..., None]).squeeze(-1) + p_d)).abs().max()
    return max(err_r.item(), err_p.item(), (gr_t - gr).abs().max().item())


@pytest.mark.parametrize("frame", ["eef", "world"])
def test_sampled_actions_are_equivariant(frame):
    policy = _policy(torch.float32, adaptation_frame=frame, squash_translations=frame == "eef")
    gen = torch.Generator().manual_seed(3)
    batch = random_batch(policy.config, 4, gen)
    noise = se3_flow.draw_local_noise(4, policy.config.horizon, 0.1, generator=gen)
    r_d, p_d = _random_transform(gen, torch.float32)
    pose, pose_t = _sample_twice(policy, batch, noise, r_d, p_d)
    assert _equivariance_error(pose, pose_t, r_d, p_d) <= 1e-4


def test_equivariance_check_fails_with_world_frame_noise():
    """Control: the same noise drawn in the world instead of the EEF frame breaks equivariance."""
    policy = _policy(torch.float32)
    gen = torch.Generator().manual_seed(4)
    batch = random_batch(policy.config, 4, gen)
    noise = se3_flow.draw_local_noise(4, policy.config.horizon, 0.1, generator=gen)
    r_d, p_d = _random_transform(gen, torch.float32)

    def world_noise_sampler(obs_r, obs_p, scalars, images, nr, np_, ng, times, points=None):
        # Pretend the EEF sits at the world origin: the noise no longer moves with the scene.
        eye_r = torch.eye(3).expand_as(obs_r[:, :1, :1]).clone()
        obs_r, obs_p = obs_r.clone(), obs_p.clone()
        obs_r[:, -1, 0] = eye_r[:, 0, 0]
        obs_p[:, -1, 0] = 0
        return ActionflowPolicy._sample(policy, obs_r, obs_p, scalars, images, nr, np_, ng, times)

    policy._sample = world_noise_sampler
    pose, pose_t = _sample_twice(policy, batch, noise, r_d, p_d)
    assert _equivariance_error(pose, pose_t, r_d, p_d) > 1e-2


def test_equivariance_check_fails_with_a_non_invariant_layer():
    """Control: mixing world-frame positions into the EEF-frame ones (a non-rigid change of
    the token frames) makes the check fail."""

    class LeakyAdaptation(PoseAdaptation):
        def __call__(self, r_ref, p_ref, r, p):
            r2, p2 = super().__call__(r_ref, p_ref, r, p)
            return r2, p2 + 0.5 * p  # every token's world position leaks in

    policy = _policy(torch.float32)
    policy.network.adaptation = LeakyAdaptation()
    gen = torch.Generator().manual_seed(5)
    batch = random_batch(policy.config, 4, gen)
    noise = se3_flow.draw_local_noise(4, policy.config.horizon, 0.1, generator=gen)
    r_d, p_d = _random_transform(gen, torch.float32)
    pose, pose_t = _sample_twice(policy, batch, noise, r_d, p_d)
    assert _equivariance_error(pose, pose_t, r_d, p_d) > 1e-2
