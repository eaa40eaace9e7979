"""Euler and midpoint solvers on SE(3) x R and in R^n: exactness on geodesic fields, and their
orders of convergence on a curved field."""

import pytest
import torch

from lerobot_actionflow import geometry as g
from lerobot_actionflow.flow import euclidean, guidance, schedules, se3

F64 = torch.float64


def _chunk(gen, b=2, h=3):
    return se3.PoseChunk(
        g.random_rotation(b, h, generator=gen, dtype=F64),
        torch.randn(b, h, 3, generator=gen, dtype=F64),
        torch.randn(b, h, generator=gen, dtype=F64),
    )


def _indexed(field, times, solver):
    """``field(x, t)`` as the solvers' index-addressed velocity."""
    at = schedules.evaluation_times(times, solver)
    return lambda x, j: field(x, at[j])


@pytest.mark.parametrize("solver", ["euler", "midpoint"])
@pytest.mark.parametrize("start", [0.0, 0.3, 0.8])
def test_both_solvers_land_on_the_target_of_a_geodesic_field(solver, start):
    """The conditional velocity of one target (constant body velocity along the geodesic) is
    integrated exactly from any start time, by either solver."""
    gen = torch.Generator().manual_seed(0)
    x, x1 = _chunk(gen), _chunk(gen)
    times = start + (1 - start) * schedules.uniform_times(3, dtype=F64)

    def field(y, t):
        return guidance.velocity_toward(y, x1, t)

    out = se3.sample(_indexed(field, times, solver), x, times, solver)
    torch.testing.assert_close(out.r, x1.r, rtol=0, atol=1e-9)
    torch.testing.assert_close(out.p, x1.p, rtol=0, atol=1e-9)
    torch.testing.assert_close(out.g, x1.g, rtol=0, atol=1e-9)


def _curved(y, t):
    """A smooth field with a turning rotation axis (non-commuting increments), a world-frame
    translation field ``-p + c(t)`` read in the body frame, and ``-g + t`` on the gripper."""
    t = torch.as_tensor(t, dtype=F64)
    w = 1.5 * torch.stack((torch.cos(3 * t), torch.sin(3 * t), torch.ones_like(t)))
    world = -y.p + torch.stack((torch.sin(t), torch.cos(2 * t), t))
    v_p = (y.r.transpose(-1, -2) @ world[..., None]).squeeze(-1)
    return se3.PoseVelocity(w.expand_as(v_p), v_p, -y.g + t)


def _error(a, b):
    rot = g.log(a.r.transpose(-1, -2) @ b.r).norm(dim=-1).max()
    return max(rot.item(), (a.p - b.p).abs().max().item(), (a.g - b.g).abs().max().item())


def test_midpoint_is_second_order_and_euler_first_order_on_se3():
    gen = torch.Generator().manual_seed(1)
    x0 = _chunk(gen)
    fine = schedules.uniform_times(512, dtype=F64)
    reference = se3.sample(_indexed(_curved, fine, "midpoint"), x0, fine, "midpoint")
    ratios = {}
    for solver in ("euler", "midpoint"):
        errs = []
        for k in (8, 16):
            times = schedules.uniform_times(k, dtype=F64)
            errs.append(_error(se3.sample(_indexed(_curved, times, solver), x0, times, solver), reference))
        ratios[solver] = errs[0] / errs[1]
    assert 1.6 < ratios["euler"] < 2.5, ratios
    assert 3.2 < ratios["midpoint"] < 5.0, ratios


def test_midpoint_in_rn_is_second_order_and_exact_on_a_constant_field():
    gen = torch.Generator().manual_seed(2)
    a0, a1 = torch.randn(2, 4, 3, generator=gen, dtype=F64), torch.randn(2, 4, 3, generator=gen, dtype=F64)
    times = schedules.uniform_times(3, dtype=F64)
    straight = euclidean.sample(lambda a, j: a1 - a0, a0, times, "midpoint")
    torch.testing.assert_close(straight, a1, rtol=0, atol=1e-12)

    def curved(a, t):
        return -a * torch.cos(3 * torch.as_tensor(t, dtype=F64))

    exact = a0 * torch.exp(torch.tensor(-torch.sin(torch.tensor(3.0)).item() / 3, dtype=F64))
    ratios = {}
    for solver in ("euler", "midpoint"):
        errs = []
        for k in (16, 32):
            times = schedules.uniform_times(k, dtype=F64)
            out = euclidean.sample(_indexed(curved, times, solver), a0, times, solver)
            errs.append((out - exact).abs().max().item())
        ratios[solver] = errs[0] / errs[1]
    assert 1.6 < ratios["euler"] < 2.5 and 3.2 < ratios["midpoint"] < 5.0, ratios


def test_midpoint_translation_uses_the_half_step_frame():
    """Control for the translation update: reading the half-step velocity in the start pose's
    frame (instead of the half pose's) misses the target of a geodesic field."""
    gen = torch.Generator().manual_seed(3)
    x, x1 = _chunk(gen), _chunk(gen)

    def wrong_step(y, velocity, v, dt):
        half = se3.euler_step(y, v, 0.5 * dt)
        w = velocity(half)
        return se3.PoseChunk(
            y.r @ g.exp(dt * w.r), y.p + dt * (y.r @ w.p[..., None]).squeeze(-1), y.g + dt * w.g
        )

    v = guidance.velocity_toward(x, x1, torch.tensor(0.0, dtype=F64))
    right = se3.midpoint_step(
        x, lambda h: guidance.velocity_toward(h, x1, torch.tensor(0.5, dtype=F64)), v, 1.0
    )
    wrong = wrong_step(x, lambda h: guidance.velocity_toward(h, x1, torch.tensor(0.5, dtype=F64)), v, 1.0)
    torch.testing.assert_close(right.p, x1.p, rtol=0, atol=1e-9)
    assert (wrong.p - x1.p).abs().max() > 1e-2


def test_unknown_solver_is_refused():
    gen = torch.Generator().manual_seed(4)
    times = schedules.uniform_times(2, dtype=F64)
    with pytest.raises(ValueError, match="rk4"):
        se3.sample(lambda x, j: None, _chunk(gen), times, "rk4")
    with pytest.raises(ValueError, match="rk4"):
        euclidean.sample(lambda a, j: a, torch.zeros(1, 2), times, "rk4")
