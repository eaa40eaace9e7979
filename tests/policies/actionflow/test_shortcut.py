"""ActionFlow with ``few_step_objective="shortcut"``: old shapes when off, a training step,
the step-size conditioning at sampling, config limits, and SE(3) equivariance (random weights and
after training) with a failing control."""

import pytest
import torch

from lerobot_actionflow.flow import se3 as se3_flow
from lerobot_actionflow.nn import PoseAdaptation
from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
from lerobot_actionflow.policies.config_errors import PolicyConfigError

from .helpers import random_batch, small_config
from .test_equivariance import _equivariance_error, _random_transform, _sample_twice


def _shortcut_policy(seed=0, **kw):
    torch.manual_seed(seed)
    return ActionflowPolicy(small_config(few_step_objective="shortcut", shortcut_max_steps=8, **kw))


def test_the_option_off_keeps_the_parameters_and_conditioning():
    torch.manual_seed(0)
    plain = ActionflowPolicy(small_config())
    short = _shortcut_policy()
    extra = set(short.state_dict()) - set(plain.state_dict())
    assert extra and all(k.startswith("network.step_size_embed.") for k in extra)
    assert set(plain.state_dict()) <= set(short.state_dict())
    t = torch.rand(3)
    for a, b in zip(plain.network.time_shifts(t), plain.network.time_shifts(t, torch.zeros(3)), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    with pytest.raises(ValueError, match="no step-size conditioning"):
        plain.network.time_shifts(t, torch.full((3,), 0.5))


def _train(policy, steps, gen, lr=3e-3):
    opt = torch.optim.Adam(policy.parameters(), lr=lr)
    policy.train()
    for _ in range(steps):
        loss, terms = policy.forward(random_batch(policy.config, 16, gen))
        opt.zero_grad()
        loss.backward()
        opt.step()
    return loss, terms


def test_a_training_step_is_finite_and_trains_the_step_size_embedding():
    policy = _shortcut_policy(shortcut_fraction=0.5)
    calls = []
    original = policy.network.velocity
    policy.network.velocity = lambda *a, **k: calls.append(a[1].p.shape[0]) or original(*a, **k)
    loss, terms = policy.forward(random_batch(policy.config, 8, torch.Generator().manual_seed(1)))
    assert torch.isfinite(loss) and all(torch.isfinite(torch.tensor(v)) for v in terms.values())
    assert calls == [4, 4, 8]  # two no-grad inner steps on the shortcut half, then the whole batch
    loss.backward()
    grads = [p.grad for p in policy.network.step_size_embed.parameters()]
    assert all(gr is not None and torch.isfinite(gr).all() for gr in grads)
    assert any(gr.abs().sum() > 0 for gr in grads)


def test_sampling_conditions_on_the_step_size_one_over_k():
    policy = _shortcut_policy().eval()
    seen = []
    original = policy.network.time_shifts
    policy.network.time_shifts = lambda t, d=None: seen.append(d) or original(t, d)
    batch = random_batch(policy.config, 2, torch.Generator().manual_seed(2))
    policy.predict_action_chunk(batch, num_inference_steps=2)
    policy.predict_action_chunk(batch, num_inference_steps=8)  # K >= shortcut_max_steps: d = 0
    torch.testing.assert_close(seen[0], torch.full((2,), 0.5))
    torch.testing.assert_close(seen[1], torch.zeros(8))
    policy.config.time_spacing = "exponential"
    with pytest.raises(ValueError, match=r"uniform time grid.*--policy.time_spacing=uniform"):
        policy.predict_action_chunk(batch, num_inference_steps=2)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"time_spacing": "exponential"}, r"uniform time grid"),
        ({"solver": "midpoint"}, r"takes Euler steps.*--policy.solver=euler"),
        ({"shortcut_fraction": 0.0}, r"`shortcut_fraction` must be in \(0, 1\]"),
        ({"shortcut_max_steps": 100}, r"`shortcut_max_steps` must be a power of two"),
        ({"few_step_objective": "consistency"}, r"`few_step_objective` must be one of"),
    ],
)
def test_shortcut_config_limits(overrides, message):
    from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig

    with pytest.raises(PolicyConfigError, match=message):
        ActionflowConfig(device="cpu", **{"few_step_objective": "shortcut", **overrides})


def _sampling_error(policy, seed):
    gen = torch.Generator().manual_seed(seed)
    batch = {k: v for k, v in random_batch(policy.config, 3, gen).items() if k != "action"}
    noise = se3_flow.draw_local_noise(3, policy.config.horizon, 0.1, generator=gen)
    r_d, p_d = _random_transform(gen, torch.float32)
    pose, pose_t = _sample_twice(policy.eval(), batch, noise, r_d, p_d)
    return _equivariance_error(pose, pose_t, r_d, p_d)


@pytest.fixture(scope="module")
def trained_shortcut_policy():
    policy = _shortcut_policy(seed=3, translation_velocity_frame="eef", shortcut_fraction=0.5)
    _train(policy, 8, torch.Generator().manual_seed(4))
    return policy.eval()


def test_shortcut_sampling_is_equivariant_with_random_weights():
    policy = _shortcut_policy(seed=5)
    policy.config.num_inference_steps = 2
    assert _sampling_error(policy, 6) <= 1e-4


def test_shortcut_sampling_is_equivariant_after_training(trained_shortcut_policy):
    trained_shortcut_policy.config.num_inference_steps = 2
    assert _sampling_error(trained_shortcut_policy, 7) <= 1e-4


def test_shortcut_equivariance_check_fails_with_a_non_invariant_layer(trained_shortcut_policy):
    """Control: world positions leaking into the token frames break it, and the check sees it."""

    class LeakyAdaptation(PoseAdaptation):
        def __call__(self, r_ref, p_ref, r, p):
            r2, p2 = super().__call__(r_ref, p_ref, r, p)
            return r2, p2 + 0.5 * p

    good = trained_shortcut_policy.network.adaptation
    trained_shortcut_policy.network.adaptation = LeakyAdaptation(
        good.frame, good.translation_scale, good.squash
    )
    try:
        assert _sampling_error(trained_shortcut_policy, 7) > 1e-2
    finally:
        trained_shortcut_policy.network.adaptation = good


def test_a_shortcut_checkpoint_reloads_with_its_step_size_embedding(trained_shortcut_policy, tmp_path):
    trained_shortcut_policy.save_pretrained(tmp_path)
    loaded = ActionflowPolicy.from_pretrained(tmp_path).eval()
    assert loaded.config.few_step_objective == "shortcut" and loaded.network.step_size_embed is not None
    gen = torch.Generator().manual_seed(8)
    batch = {k: v for k, v in random_batch(loaded.config, 2, gen).items() if k != "action"}
    noise = se3_flow.draw_local_noise(2, loaded.config.horizon, 0.1, generator=gen)
    torch.testing.assert_close(
        loaded.predict_action_chunk(batch, noise=noise, num_inference_steps=2),
        trained_shortcut_policy.predict_action_chunk(batch, noise=noise, num_inference_steps=2),
    )
