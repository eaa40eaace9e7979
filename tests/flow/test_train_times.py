"""Training-time distributions: the logit-normal law ``t = sigmoid(N(mean, std^2))``."""

import math

import pytest
import torch

from lerobot_actionflow.flow import schedules


@pytest.mark.parametrize(("mean", "std"), [(0.0, 1.0), (0.8, 0.5), (-1.0, 1.5)])
def test_logit_normal_times_have_the_requested_logit_moments(mean, std):
    gen = torch.Generator().manual_seed(0)
    n = 40_000
    t = schedules.sample_train_times(
        n, "logit_normal", generator=gen, dtype=torch.float64, logit_normal=(mean, std)
    )
    assert t.shape == (n,) and (t > 0).all() and (t < 1).all()
    z = torch.logit(t)
    # Standard errors: std / sqrt(n) for the mean, about std / sqrt(2 n) for the std.
    assert abs(z.mean().item() - mean) < 5 * std / math.sqrt(n)
    assert abs(z.std().item() - std) < 5 * std / math.sqrt(2 * n)
    assert abs(t.median().item() - 1 / (1 + math.exp(-mean))) < 0.01
    # Control: uniform times do not have these logit moments (their logit std is pi / sqrt(3)).
    u = torch.logit(schedules.sample_train_times(n, "uniform", generator=gen, dtype=torch.float64))
    assert abs(u.std().item() - std) > 0.2


def test_logit_normal_refuses_a_bad_std():
    with pytest.raises(ValueError, match="std > 0"):
        schedules.sample_train_times(4, "logit_normal", logit_normal=(0.0, 0.0))
    with pytest.raises(ValueError, match="logit_normal"):
        schedules.sample_train_times(4, "lognormal")


def test_evaluation_times_of_each_solver():
    times = torch.tensor([0.0, 0.25, 1.0])
    torch.testing.assert_close(schedules.evaluation_times(times, "euler"), times[:-1])
    torch.testing.assert_close(
        schedules.evaluation_times(times, "midpoint"), torch.tensor([0.0, 0.125, 0.25, 0.625])
    )
    assert schedules.network_calls(3, "euler") == 3 and schedules.network_calls(3, "midpoint") == 6
    with pytest.raises(ValueError, match="heun"):
        schedules.evaluation_times(times, "heun")
