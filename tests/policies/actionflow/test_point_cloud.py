"""ActionFlow with point-cloud tokens: exact SE(3) equivariance through the public path, with
controls that must fail, and the config / input errors."""

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow import geometry as g
from lerobot_actionflow.flow import se3 as se3_flow
from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
from lerobot_actionflow.schema import POINT_CLOUD_KEY
from lerobot_actionflow.schema.tensors import action_to_pose

from .helpers import random_batch, small_config, transform_batch

M = 48


def _config(num_points=M, **kw):
    cfg = small_config(point_cloud_key=POINT_CLOUD_KEY, point_cloud_groups=8, point_cloud_group_size=6,
                       point_cloud_width=16, **kw)  # fmt: skip
    cfg.input_features[POINT_CLOUD_KEY] = PolicyFeature(FeatureType.STATE, (num_points, 3))
    return cfg


def _policy(dtype=torch.float32, seed=0, **kw):
    torch.manual_seed(seed)
    return ActionflowPolicy(_config(**kw)).to(dtype).eval()


def _batch(policy, gen, b=3, dtype=torch.float32):
    batch = random_batch(policy.config, b, gen, dtype)
    batch[POINT_CLOUD_KEY] = 0.3 * torch.randn(b, policy.config.n_obs_steps, M, 3, generator=gen, dtype=dtype)
    return batch


def _transform(batch, r_d, p_d):
    out = transform_batch(batch, r_d, p_d)
    out[POINT_CLOUD_KEY] = batch[POINT_CLOUD_KEY] @ r_d.T + p_d
    return out


def _equivariance_error(policy, batch, r_d, p_d, gen, transform=_transform):
    noise = se3_flow.draw_local_noise(
        batch[POINT_CLOUD_KEY].shape[0], policy.config.horizon, 0.1, generator=gen, dtype=r_d.dtype
    )
    r, p, gr = action_to_pose(policy.predict_action_chunk(batch, noise=noise))
    r_t, p_t, gr_t = action_to_pose(policy.predict_action_chunk(transform(batch, r_d, p_d), noise=noise))
    err_r = (r_t - r_d @ r).abs().max()
    err_p = (p_t - (p @ r_d.T + p_d)).abs().max()
    return max(err_r.item(), err_p.item(), (gr_t - gr).abs().max().item())


@pytest.mark.parametrize(("dtype", "tol"), [(torch.float32, 1e-5), (torch.float64, 1e-10)])
def test_sampled_actions_are_equivariant_with_point_clouds(dtype, tol):
    policy = _policy(dtype)
    gen = torch.Generator().manual_seed(1)
    batch = _batch(policy, gen, dtype=dtype)
    r_d, p_d = g.random_rotation(generator=gen, dtype=dtype), torch.randn(3, generator=gen, dtype=dtype)
    assert _equivariance_error(policy, batch, r_d, p_d, gen) <= tol


def test_equivariant_with_world_frame_adaptation():
    """With adaptation_frame='world' nothing is re-expressed in the EEF frame: the point tokens'
    frames must move rigidly with the scene for IPA alone to keep the invariance."""
    policy = _policy(adaptation_frame="world", squash_translations=False)
    gen = torch.Generator().manual_seed(10)
    batch = _batch(policy, gen)
    r_d, p_d = g.random_rotation(generator=gen), torch.randn(3, generator=gen)
    assert _equivariance_error(policy, batch, r_d, p_d, gen) <= 1e-5


def test_point_tokens_change_the_actions():
    """The cloud is read: moving one object's points changes the sampled chunk."""
    policy = _policy()
    gen = torch.Generator().manual_seed(2)
    batch = _batch(policy, gen)
    noise = se3_flow.draw_local_noise(3, policy.config.horizon, 0.1, generator=gen)
    a = policy.predict_action_chunk(batch, noise=noise)
    moved = dict(batch)
    moved[POINT_CLOUD_KEY] = (
        batch[POINT_CLOUD_KEY] + torch.tensor([0.05, 0.0, 0.0]) * (torch.arange(M) < M // 2)[:, None]
    )
    assert (policy.predict_action_chunk(moved, noise=noise) - a).abs().max() > 1e-3


def test_control_untransformed_cloud_breaks_equivariance():
    """Control: poses moved but the cloud left in place must fail the check."""
    policy = _policy()
    gen = torch.Generator().manual_seed(3)
    batch = _batch(policy, gen)
    r_d, p_d = g.random_rotation(generator=gen), torch.randn(3, generator=gen)

    def poses_only(b, r, p):
        return {**transform_batch(b, r, p), POINT_CLOUD_KEY: b[POINT_CLOUD_KEY]}

    assert _equivariance_error(policy, batch, r_d, p_d, gen, poses_only) > 1e-2


def test_control_world_frame_offsets_break_equivariance(monkeypatch):
    """Control: neighbour offsets expressed in the world frame (not the token's) must fail."""
    policy = _policy()
    tokenizer = policy.network.point_tokens
    original = type(tokenizer).forward

    def world_offsets(self, points, r_ref, scale):
        return original(self, points, torch.eye(3).expand_as(r_ref), scale)

    monkeypatch.setattr(type(tokenizer), "forward", world_offsets)
    gen = torch.Generator().manual_seed(4)
    batch = _batch(policy, gen)
    r_d, p_d = g.random_rotation(generator=gen), torch.randn(3, generator=gen)
    assert _equivariance_error(policy, batch, r_d, p_d, gen) > 1e-3


def test_point_cloud_prefix_reads_only_the_first_rows_and_stays_equivariant():
    policy = _policy(point_cloud_prefix=20)
    gen = torch.Generator().manual_seed(11)
    batch = _batch(policy, gen)
    noise = se3_flow.draw_local_noise(3, policy.config.horizon, 0.1, generator=gen)
    a = policy.predict_action_chunk(batch, noise=noise)
    tail_moved = {**batch, POINT_CLOUD_KEY: batch[POINT_CLOUD_KEY].clone()}
    tail_moved[POINT_CLOUD_KEY][..., 20:, :] += 0.5
    torch.testing.assert_close(policy.predict_action_chunk(tail_moved, noise=noise), a, rtol=0, atol=0)
    whole = _policy()  # control: the same weights reading all M rows see the tail move
    assert (
        whole.predict_action_chunk(tail_moved, noise=noise) - whole.predict_action_chunk(batch, noise=noise)
    ).abs().max() > 1e-3
    head_moved = {**batch, POINT_CLOUD_KEY: batch[POINT_CLOUD_KEY].clone()}
    head_moved[POINT_CLOUD_KEY][..., :10, :] += 0.05  # control: the rows it reads do matter
    assert (policy.predict_action_chunk(head_moved, noise=noise) - a).abs().max() > 1e-3
    r_d, p_d = g.random_rotation(generator=gen), torch.randn(3, generator=gen)
    assert _equivariance_error(policy, batch, r_d, p_d, gen) <= 1e-5


def test_point_cloud_prefix_outside_the_groups_or_the_cloud_is_refused_by_name():
    with pytest.raises(ValueError, match=r"`point_cloud_prefix` must be an integer >= 8"):
        _config(point_cloud_prefix=4)  # fewer than the 8 groups
    with pytest.raises(ValueError, match=r"`point_cloud_prefix` is 20 but `point_cloud_key` is None"):
        small_config(point_cloud_prefix=20)
    with pytest.raises(ValueError, match=r"M=48 points, fewer than the 64"):
        ActionflowPolicy(_config(point_cloud_prefix=64))


def test_select_action_reads_float16_clouds():
    policy = _policy()
    gen = torch.Generator().manual_seed(5)
    batch = _batch(policy, gen, b=2)
    step = {k: v[:, -1] for k, v in batch.items() if k != "action"}
    step[POINT_CLOUD_KEY] = step[POINT_CLOUD_KEY].half()
    action = policy.select_action(step)
    assert action.shape == (2, 10) and action.dtype == torch.float32 and torch.isfinite(action).all()


def test_training_step_reaches_the_point_encoder():
    policy = _policy().train()
    gen = torch.Generator().manual_seed(6)
    loss, _ = policy.forward(_batch(policy, gen, b=4))
    loss.backward()
    grads = [p.grad for p in policy.network.point_tokens.parameters()]
    assert all(gr is not None and torch.isfinite(gr).all() for gr in grads)
    assert any(gr.abs().sum() > 0 for gr in grads)


def test_missing_or_misshapen_cloud_is_refused_by_name():
    cfg = small_config(point_cloud_key=POINT_CLOUD_KEY)
    with pytest.raises(ValueError, match=r"point_cloud_key is 'observation.point_cloud'.*no such feature"):
        ActionflowPolicy(cfg)
    cfg.input_features[POINT_CLOUD_KEY] = PolicyFeature(FeatureType.STATE, (64, 4))
    with pytest.raises(
        ValueError, match=r"'observation.point_cloud' must have shape \(M, 3\), got \(64, 4\)"
    ):
        ActionflowPolicy(cfg)
    cfg.input_features[POINT_CLOUD_KEY] = PolicyFeature(FeatureType.STATE, (8, 3))
    with pytest.raises(ValueError, match=r"M=8 points, fewer than the 32"):
        ActionflowPolicy(cfg)
    with pytest.raises(ValueError, match="point_cloud_groups"):
        small_config(point_cloud_key=POINT_CLOUD_KEY, point_cloud_groups=0)
    with pytest.raises(ValueError, match="point_cloud_key"):
        small_config(point_cloud_key="point_cloud")


def test_batch_with_a_wrong_cloud_is_refused_by_name():
    policy = _policy()
    gen = torch.Generator().manual_seed(7)
    batch = _batch(policy, gen)
    batch[POINT_CLOUD_KEY] = batch[POINT_CLOUD_KEY][:, :, :10]
    with pytest.raises(
        ValueError, match=r"input feature 'observation.point_cloud' has shape \(3, 2, 10, 3\)"
    ):
        policy.predict_action_chunk(batch)
    del batch[POINT_CLOUD_KEY]
    with pytest.raises(ValueError, match=r"missing input feature 'observation\.point_cloud'"):
        policy.predict_action_chunk(batch)


def test_a_cloud_in_the_dataset_is_ignored_without_the_key():
    cfg = small_config()
    cfg.input_features[POINT_CLOUD_KEY] = PolicyFeature(FeatureType.STATE, (M, 3))
    policy = ActionflowPolicy(cfg)
    assert policy.network.point_tokens is None
    assert not any(k.startswith(("network.point_tokens", "network.point_embed")) for k in policy.state_dict())


def test_export_refuses_point_cloud_policies(tmp_path):
    from lerobot_actionflow.policies.exported import export_sampler

    with pytest.raises(ValueError, match=r"reads the point cloud 'observation\.point_cloud'"):
        export_sampler(_policy(), tmp_path, num_inference_steps=2)


def test_pose_entities_hide_the_other_rows():
    """``pose_entities=(0,)``: the objects' pose rows are not read (changing them changes nothing),
    and the point-cloud policy stays equivariant."""
    policy = _policy(pose_entities=(0,))
    assert policy.num_entities == 1
    gen = torch.Generator().manual_seed(9)
    batch = _batch(policy, gen)
    noise = se3_flow.draw_local_noise(3, policy.config.horizon, 0.1, generator=gen)
    a = policy.predict_action_chunk(batch, noise=noise)
    moved = dict(batch)
    moved["observation.poses"] = batch["observation.poses"].clone()
    moved["observation.poses"][:, :, 1:, :3] += 1.0
    assert torch.equal(policy.predict_action_chunk(moved, noise=noise), a)
    r_d, p_d = g.random_rotation(generator=gen), torch.randn(3, generator=gen)
    assert _equivariance_error(policy, batch, r_d, p_d, gen) <= 1e-5
    with pytest.raises(ValueError, match="pose_entities"):
        small_config(pose_entities=(1, 0))
    with pytest.raises(ValueError, match=r"pose_entities \[7\] are outside the 4 rows"):
        ActionflowPolicy(_config(pose_entities=(0, 7)))
