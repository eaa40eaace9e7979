"""euclidean_flow policy: config checks, input validation, inference knobs, backbones, LeRobot
factory lookup by naming convention, processors."""

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow.flow.schedules import make_time_grid
from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig
from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy

STATE, ENV, ACT = 11, 9, 10


def _features(images: bool = False):
    inputs = {
        "observation.state": PolicyFeature(FeatureType.STATE, (STATE,)),
        "observation.environment_state": PolicyFeature(FeatureType.ENV, (ENV,)),
        "observation.poses": PolicyFeature(FeatureType.STATE, (2, 7)),  # ignored by the policy
    }
    if images:
        inputs["observation.images.cam"] = PolicyFeature(FeatureType.VISUAL, (3, 32, 32))
    return inputs, {"action": PolicyFeature(FeatureType.ACTION, (ACT,))}


def _config(backbone="transformer", images=False, **kw):
    inputs, outputs = _features(images)
    small = dict(n_layer=1, n_emb=32, down_dims=(16, 32), diffusion_step_embed_dim=16, n_groups=4)
    small.update(kw)
    return EuclideanFlowConfig(
        device="cpu",
        backbone=backbone,
        horizon=8,
        n_action_steps=4,
        input_features=inputs,
        output_features=outputs,
        **small,
    )


def _batch(b=2, s=2, h=8, images=False):
    batch = {
        "observation.state": torch.randn(b, s, STATE),
        "observation.environment_state": torch.randn(b, s, ENV),
        "action": torch.rand(b, h, ACT) * 2 - 1,
        "action_is_pad": torch.zeros(b, h, dtype=torch.bool),
    }
    if images:
        batch["observation.images.cam"] = torch.rand(b, s, 3, 32, 32)
    return batch


@pytest.mark.parametrize(
    ("backbone", "images"), [("transformer", False), ("unet", False), ("transformer", True)]
)
def test_train_step_and_chunk_shapes(backbone, images):
    torch.manual_seed(0)
    policy = EuclideanFlowPolicy(_config(backbone, images))
    loss, _ = policy.forward(_batch(images=images))
    loss.backward()
    assert loss.ndim == 0 and torch.isfinite(loss)
    assert all(p.grad is not None for p in policy.velocity_net.parameters() if p.requires_grad)
    per_sample, _ = policy.forward(_batch(b=3, images=images), reduction="none")
    assert per_sample.shape == (3,)
    policy.eval()
    # the chunk from the current step on: horizon 8 from the oldest of 2 observation steps
    assert policy.predict_action_chunk(_batch(images=images)).shape == (2, 7, ACT)
    step = {k: v[:, -1] for k, v in _batch(images=images).items() if k.startswith("observation")}
    actions = [policy.select_action(step) for _ in range(5)]
    assert all(a.shape == (2, ACT) for a in actions)
    assert len(policy._queues["action"]) == 3  # a new chunk of 4 at calls 1 and 5


def test_loss_is_the_rectified_flow_objective(monkeypatch):
    """With a network that outputs the exact conditional velocity a_1 - a_0, the loss is 0."""
    policy = EuclideanFlowPolicy(_config())
    batch = _batch()
    noise = torch.randn_like(batch["action"])
    monkeypatch.setattr(torch, "randn_like", lambda x: noise)
    target = batch["action"] - noise
    policy.velocity_net.forward = lambda x, t, cond: target
    loss, _ = policy.forward(batch)
    assert loss.item() == pytest.approx(0.0, abs=1e-12)
    policy.velocity_net.forward = lambda x, t, cond: target + 1.0
    assert policy.forward(batch)[0].item() == pytest.approx(1.0)


def test_inference_steps_and_spacing_change_without_retraining():
    policy = EuclideanFlowPolicy(_config()).eval()
    seen = []
    policy.velocity_net.register_forward_hook(lambda m, args, out: seen.append(args[1][0].item()))
    for k, spacing in [(2, "uniform"), (5, "exponential"), (3, None)]:
        seen.clear()
        policy.predict_action_chunk(_batch(), num_inference_steps=k, time_spacing=spacing)
        grid = make_time_grid(k, spacing or policy.config.time_spacing, rate=policy.config.time_spacing_rate)
        assert seen == pytest.approx(grid[:-1].tolist())  # K network calls at t_0..t_{K-1}
    policy.config.num_inference_steps = 7  # what --policy.num_inference_steps=7 does
    seen.clear()
    policy.predict_action_chunk(_batch())
    assert len(seen) == 7


def test_same_noise_same_actions_and_clipping():
    policy = EuclideanFlowPolicy(_config()).eval()
    noise, batch = torch.randn(2, 8, ACT) * 10, _batch()
    a = policy.predict_action_chunk(batch, noise=noise)
    assert torch.equal(a, policy.predict_action_chunk(batch, noise=noise))
    assert a.abs().max() <= 1.0
    policy.config.clip_sample = False
    assert policy.predict_action_chunk(batch, noise=noise).abs().max() > 1.0


def test_unet_backbone_is_lerobots_unet_fed_scaled_time():
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionConditionalUnet1d

    policy = EuclideanFlowPolicy(_config("unet")).eval()
    unet = policy.velocity_net.unet
    assert type(unet) is DiffusionConditionalUnet1d
    seen = []
    unet.register_forward_hook(lambda m, args, out: seen.append(args[1].clone()))
    policy.predict_action_chunk(_batch(), num_inference_steps=2, time_spacing="uniform")
    assert [s.tolist() for s in seen] == [[0.0, 0.0], [500.0, 500.0]]  # t * time_embed_scale


def test_bad_inputs_raise_clear_errors():
    policy = EuclideanFlowPolicy(_config()).eval()
    batch = _batch()
    del batch["observation.environment_state"]
    with pytest.raises(
        ValueError, match=r"missing input feature 'observation.environment_state'.*\(B, 2, 9\)"
    ):
        policy.forward(batch)
    batch = _batch()
    batch["observation.state"] = torch.randn(2, 2, 7)
    with pytest.raises(ValueError, match=r"'observation.state' has shape \(2, 2, 7\).*expected \(B, 2, 11\)"):
        policy.predict_action_chunk(batch)
    batch = _batch()
    batch["observation.state"][0, 1, 3] = float("nan")
    with pytest.raises(ValueError, match=r"'observation.state' contains non-finite"):
        policy.forward(batch)
    batch = _batch()
    batch["action"][1, 0, 0] = float("inf")
    with pytest.raises(ValueError, match=r"'action' contains non-finite"):
        policy.forward(batch)
    batch = _batch(h=5)
    with pytest.raises(ValueError, match=r"'action' has shape \(2, 5, 10\), expected \(B, 8, 10\)"):
        policy.forward(batch)
    with pytest.raises(ValueError, match=r"missing input feature 'observation.state'.*\(B, 11\)"):
        policy.select_action({"observation.environment_state": torch.zeros(1, ENV)})
    # poses are not used, so their absence is fine
    assert "observation.poses" not in policy.config.used_input_features


def test_config_validation():
    inputs, outputs = _features()
    with pytest.raises(ValueError, match="backbone"):
        EuclideanFlowConfig(device="cpu", backbone="mlp")
    with pytest.raises(ValueError, match="time_spacing"):
        EuclideanFlowConfig(device="cpu", time_spacing="cosine")
    with pytest.raises(ValueError, match="n_action_steps"):
        EuclideanFlowConfig(device="cpu", horizon=8, n_obs_steps=2, n_action_steps=8)
    with pytest.raises(ValueError, match="multiple of 4"):
        EuclideanFlowConfig(device="cpu", backbone="unet", horizon=10, n_action_steps=4)
    with pytest.raises(ValueError, match="num_inference_steps"):
        EuclideanFlowConfig(device="cpu", num_inference_steps=0)
    cfg = EuclideanFlowConfig(
        device="cpu",
        input_features={"observation.poses": inputs["observation.poses"]},
        output_features=outputs,
    )
    with pytest.raises(ValueError, match="at least one observation input"):
        cfg.validate_features()
    cfg = EuclideanFlowConfig(device="cpu", input_features=inputs, output_features={})
    with pytest.raises(ValueError, match="output feature 'action'"):
        cfg.validate_features()


def test_lerobot_factory_finds_policy_and_processors_by_convention():
    from lerobot.policies.factory import get_policy_class, make_policy_config, make_pre_post_processors

    assert get_policy_class("euclidean_flow") is EuclideanFlowPolicy
    cfg = make_policy_config("euclidean_flow", device="cpu", n_layer=1, n_emb=32)
    assert isinstance(cfg, EuclideanFlowConfig)
    cfg.input_features, cfg.output_features = _features()
    stats = {
        "observation.state": {"min": torch.zeros(STATE), "max": torch.full((STATE,), 2.0)},
        "observation.environment_state": {"min": torch.zeros(ENV), "max": torch.full((ENV,), 2.0)},
        "observation.poses": {"min": torch.zeros(2, 7), "max": torch.full((2, 7), 2.0)},
        "action": {"min": torch.zeros(ACT), "max": torch.full((ACT,), 4.0)},
    }
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    obs = {
        "observation.state": torch.ones(STATE),
        "observation.environment_state": torch.full((ENV,), 2.0),
        "observation.poses": torch.ones(2, 7),
    }
    out = pre(obs)
    assert torch.allclose(out["observation.state"], torch.zeros(1, STATE))  # min-max to [-1, 1]
    assert torch.allclose(out["observation.environment_state"], torch.ones(1, ENV))
    assert torch.equal(out["observation.poses"].reshape(2, 7), torch.ones(2, 7))  # not normalised
    assert torch.allclose(post(torch.zeros(1, ACT)), torch.full((1, ACT), 2.0))


@pytest.mark.parametrize("backbone", ["transformer", "unet"])
def test_save_and_reload_give_identical_actions(backbone, tmp_path):
    policy = EuclideanFlowPolicy(_config(backbone, num_inference_steps=3)).eval()
    policy.save_pretrained(tmp_path)
    again = EuclideanFlowPolicy.from_pretrained(tmp_path)
    assert again.config.backbone == backbone and tuple(again.config.down_dims) == (16, 32)
    assert again.config.num_inference_steps == 3
    batch, noise = _batch(), torch.randn(2, 8, ACT)
    assert torch.equal(
        policy.predict_action_chunk(batch, noise=noise), again.predict_action_chunk(batch, noise=noise)
    )


def test_padding_mask_excludes_padded_actions(monkeypatch):
    policy = EuclideanFlowPolicy(_config(do_mask_loss_for_padding=True))
    batch = _batch()
    batch["action_is_pad"][:, 5:] = True
    noise = torch.randn_like(batch["action"])
    monkeypatch.setattr(torch, "randn_like", lambda x: noise)
    wrong_on_pad = batch["action"] - noise
    wrong_on_pad[:, 5:] += 100.0
    policy.velocity_net.forward = lambda x, t, cond: wrong_on_pad
    assert policy.forward(batch)[0].item() == pytest.approx(0.0, abs=1e-12)
    policy.config.do_mask_loss_for_padding = False
    assert policy.forward(batch)[0].item() > 1000
