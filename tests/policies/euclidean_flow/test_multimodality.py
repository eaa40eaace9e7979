"""A flow policy represents two action modes for one observation instead of averaging them."""

import pytest
import torch


def _mode_fractions(policy, num_steps: int, spacing: str, n: int = 400):
    torch.manual_seed(1)
    obs = {"observation.state": torch.zeros(n, 1, 3)}
    chunks = policy.predict_action_chunk(obs, num_inference_steps=num_steps, time_spacing=spacing)
    m = chunks.mean(dim=(1, 2))  # one number per sampled chunk; the modes are +1 and -1
    return (
        (m > 0.5).float().mean().item(),
        (m < -0.5).float().mean().item(),
        (m.abs() < 0.5).float().mean().item(),
    )


@pytest.mark.parametrize("spacing", ["uniform", "exponential"])
def test_samples_cover_both_modes_without_averaging(bimodal_policy, spacing):
    pos, neg, mid = _mode_fractions(bimodal_policy, 10, spacing)
    assert pos >= 0.2 and neg >= 0.2, f"a mode is missing: +1 {pos:.2f}, -1 {neg:.2f}"
    assert mid <= 0.15, f"{mid:.0%} of the samples average the modes"


def test_one_euler_step_averages_the_modes(bimodal_policy):
    """A single Euler step from t=0 returns the learned mean velocity target, E[a_1]: the
    regression answer. It proves the check above can fail, and that K reaches the sampler."""
    pos, neg, mid = _mode_fractions(bimodal_policy, 1, "uniform")
    assert mid >= 0.8, (pos, neg, mid)
