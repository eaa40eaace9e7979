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


@pytest.mark.parametrize(
    ("frame", "velocity_frame"), [("eef", "pose"), ("world", "pose"), ("eef", "eef"), ("world", "eef")]
)
def test_sampled_actions_are_equivariant(frame, velocity_frame):
    policy = _policy(
        torch.float32,
        adaptation_frame=frame,
        squash_translations=frame == "eef",
        translation_velocity_frame=velocity_frame,
    )
    gen = torch.Generator().manual_seed(3)
    batch = random_batch(policy.config, 4, gen)
    noise = se3_flow.draw_local_noise(4, policy.config.horizon, 0.1, generator=gen)
    r_d, p_d = _random_transform(gen, torch.float32)
    pose, pose_t = _sample_twice(policy, batch, noise, r_d, p_d)
    assert _equivariance_error(pose, pose_t, r_d, p_d) <= 1e-4


@pytest.mark.parametrize("rotation", ["uniform", "concentrated"])
def test_chunks_from_the_policys_own_noise_are_equivariant(rotation):
    """Without given noise the policy draws it itself (``noise_rotation``, in the EEF frame): the
    same random state gives transformed chunks for a transformed scene, with either rotation
    distribution; the other distribution from the same state gives other chunks (control: the
    option reaches the draw)."""
    policy = _policy(torch.float32, noise_rotation=rotation)
    other = _policy(
        torch.float32, noise_rotation={"uniform": "concentrated", "concentrated": "uniform"}[rotation]
    )
    gen = torch.Generator().manual_seed(8)
    batch = random_batch(policy.config, 4, gen)
    r_d, p_d = _random_transform(gen, torch.float32)
    chunks = []
    for p, b in ((policy, batch), (policy, transform_batch(batch, r_d, p_d)), (other, batch)):
        torch.manual_seed(5)
        chunks.append(action_to_pose(p.predict_action_chunk(b)))
    assert _equivariance_error(chunks[0], chunks[1], r_d, p_d) <= 1e-4
    assert (chunks[0][0] - chunks[2][0]).abs().max() > 1e-2


def test_eef_velocity_frame_reads_the_head_in_the_eef_frame():
    """With ``translation_velocity_frame='eef'`` the same weights give ``v_p = r^T R_e u``, where
    ``u`` is what the ``'pose'`` network returns; the rotation and gripper channels are unchanged."""
    gen = torch.Generator().manual_seed(6)
    pose_policy = _policy(torch.float64)
    eef_policy = _policy(torch.float64, translation_velocity_frame="eef")
    eef_policy.load_state_dict(pose_policy.state_dict())
    batch = random_batch(pose_policy.config, 3, gen, torch.float64)
    t = torch.rand(3, generator=gen, dtype=torch.float64)
    with torch.no_grad():
        u = _velocities(pose_policy, batch, t)
        v = _velocities(eef_policy, batch, t)
    r_a = action_to_pose(batch["action"])[0]
    r_e = g.se3.pose7_to_rp(batch["observation.poses"])[0][:, -1, 0]
    expected = (r_a.transpose(-1, -2) @ r_e[:, None] @ u.p[..., None]).squeeze(-1)
    torch.testing.assert_close(v.p, expected, rtol=0, atol=1e-12)
    torch.testing.assert_close(v.r, u.r, rtol=0, atol=0)
    assert (v.p - u.p).abs().max() > 1e-3  # control: the two frames differ


def test_eef_frame_translation_target_is_constant_along_the_path():
    """The reason for ``'eef'``: ``R_e^T (p_1 - p_0)`` does not depend on ``t``, while the
    pose-frame target ``r_t^T (p_1 - p_0)`` turns with the rotation noise (control)."""
    gen = torch.Generator().manual_seed(7)
    b, h = 2, 5
    r_e = g.random_rotation(b, generator=gen, dtype=torch.float64)
    p_e = torch.randn(b, 3, generator=gen, dtype=torch.float64)
    noise = se3_flow.draw_local_noise(b, h, 0.1, generator=gen, dtype=torch.float64)
    x0 = se3_flow.noise_to_world(noise, r_e, p_e)
    x1 = se3_flow.PoseChunk(
        g.random_rotation(b, h, generator=gen, dtype=torch.float64),
        torch.randn(b, h, 3, generator=gen, dtype=torch.float64),
        torch.zeros(b, h, dtype=torch.float64),
    )
    in_eef, in_pose = [], []
    for t in (0.1, 0.5, 0.9):
        x_t, u_t = se3_flow.geodesic_path(x0, x1, torch.full((b,), t, dtype=torch.float64))
        world = (x_t.r @ u_t.p[..., None]).squeeze(-1)
        in_eef.append((r_e.transpose(-1, -2)[:, None] @ world[..., None]).squeeze(-1))
        in_pose.append(u_t.p)
    torch.testing.assert_close(in_eef[0], in_eef[2], rtol=0, atol=1e-12)
    assert (in_pose[0] - in_pose[2]).abs().max() > 1e-2


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
