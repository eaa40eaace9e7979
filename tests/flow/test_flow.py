"""Flow matching laws: paths hit their endpoints, exact velocities integrate to the data,
time grids are monotone, and the EEF-frame noise transforms with the frame."""

import math

import pytest
import torch

from lerobot_actionflow import geometry as g
from lerobot_actionflow.flow import euclidean, schedules, se3


def _chunk(b, h, gen, dtype=torch.float64):
    return (
        g.random_rotation(b, h, generator=gen, dtype=dtype),
        torch.randn(b, h, 3, generator=gen, dtype=dtype),
        torch.randn(b, h, generator=gen, dtype=dtype),
    )


def test_time_grids():
    u = schedules.uniform_times(4, dtype=torch.float64)
    assert torch.allclose(u, torch.tensor([0, 0.25, 0.5, 0.75, 1.0], dtype=torch.float64))
    e = schedules.exponential_times(5, rate=2.0, dtype=torch.float64)
    assert e[0] == 0 and e[-1] == 1
    dt = e.diff()
    assert (dt > 0).all() and (dt.diff() < 0).all(), "steps must shrink towards t = 1"
    assert torch.allclose(dt[1:] / dt[:-1], torch.full((4,), math.exp(-2.0 / 5), dtype=torch.float64))
    assert torch.allclose(schedules.make_time_grid(3, "exponential", rate=0.0), schedules.uniform_times(3))
    with pytest.raises(ValueError, match="spacing"):
        schedules.make_time_grid(3, "cosine")
    with pytest.raises(ValueError, match=">= 1"):
        schedules.uniform_times(0)


def test_train_times_in_unit_interval():
    for dist in ("uniform", "beta"):
        t = schedules.sample_train_times(1000, dist)
        assert t.shape == (1000,) and (t >= 0).all() and (t <= 1).all()
    with pytest.raises(ValueError, match="distribution"):
        schedules.sample_train_times(3, "normal")


@pytest.mark.parametrize("k", [1, 3])
def test_euclidean_flow_exact_velocity_reaches_data(k):
    gen = torch.Generator().manual_seed(0)
    a0, a1 = torch.randn(8, 16, 10, generator=gen), torch.randn(8, 16, 10, generator=gen)
    at, u = euclidean.linear_path(a0, a1, torch.zeros(8))
    assert torch.equal(at, a0) and torch.equal(u, a1 - a0)
    out = euclidean.euler_sample(lambda a, k: a1 - a0, a0, schedules.exponential_times(k))
    assert torch.allclose(out, a1, atol=1e-5)


def test_se3_path_endpoints_and_velocity_consistency():
    gen = torch.Generator().manual_seed(1)
    x0 = se3.PoseChunk(*_chunk(4, 16, gen))
    x1 = se3.PoseChunk(*_chunk(4, 16, gen))
    start = se3.geodesic_path(x0, x1, torch.zeros(4, dtype=torch.float64)).x_t
    assert torch.allclose(start.r, x0.r, atol=1e-12) and torch.allclose(start.p, x0.p)
    assert torch.allclose(start.g, x0.g)
    end = se3.geodesic_path(x0, x1, torch.ones(4, dtype=torch.float64)).x_t
    assert torch.allclose(end.r, x1.r, atol=1e-10) and torch.allclose(end.p, x1.p)
    assert torch.allclose(end.g, x1.g)
    # The local velocities are the derivative of the path: a tiny Euler step follows it.
    t = torch.rand(4, generator=gen, dtype=torch.float64) * 0.9
    x_t, u_t = se3.geodesic_path(x0, x1, t)
    h = 1e-6
    ahead = se3.geodesic_path(x0, x1, t + h).x_t
    stepped = se3.euler_step(x_t, u_t, h)
    for a, b in zip(stepped, ahead, strict=True):
        assert torch.allclose(a, b, atol=1e-10)
    # Control: the translation velocity read in the world frame instead of the pose's does not
    # follow the path (this is what the local frame convention guards).
    world = se3.PoseVelocity(u_t.r, (x_t.r @ u_t.p[..., None]).squeeze(-1), u_t.g)
    assert not torch.allclose(se3.euler_step(x_t, world, h).p, ahead.p, atol=1e-10)


@pytest.mark.parametrize("spacing", ["uniform", "exponential"])
def test_se3_euler_with_exact_field_lands_on_data(spacing):
    """The conditional field of a single target is integrated exactly by Euler on the group."""
    gen = torch.Generator().manual_seed(2)
    x0 = se3.PoseChunk(*_chunk(3, 5, gen))
    r1, p1, g1 = _chunk(3, 5, gen)
    times = schedules.make_time_grid(4, spacing, dtype=torch.float64)

    def exact(x, k):
        # Velocity that points from the current pose to the target, reached at t = 1.
        rem = 1 - times[k]
        v_r = g.log(x.r.transpose(-1, -2) @ r1) / rem
        v_p = (x.r.transpose(-1, -2) @ ((p1 - x.p) / rem)[..., None]).squeeze(-1)
        return se3.PoseVelocity(v_r, v_p, (g1 - x.g) / rem)

    out = se3.euler_sample(exact, x0, times)
    assert torch.allclose(out.r, r1, atol=1e-9) and torch.allclose(out.p, p1, atol=1e-9)
    assert torch.allclose(out.g, g1)


def test_local_noise_moves_with_the_reference_frame():
    gen = torch.Generator().manual_seed(3)
    noise = se3.draw_local_noise(2, 16, sigma=0.05, generator=gen, dtype=torch.float64)
    assert g.rotation_error(noise.r).max() < 1e-12
    assert abs(noise.p.std().item() - 0.05) < 0.02
    r_e, p_e = (
        g.random_rotation(2, generator=gen, dtype=torch.float64),
        torch.randn(2, 3, generator=gen, dtype=torch.float64),
    )
    r_d, p_d = (
        g.random_rotation(generator=gen, dtype=torch.float64),
        torch.randn(3, generator=gen, dtype=torch.float64),
    )
    r, p, _ = se3.noise_to_world(noise, r_e, p_e)
    r2, p2, _ = se3.noise_to_world(noise, r_d @ r_e, (r_d @ p_e[..., None]).squeeze(-1) + p_d)
    assert torch.allclose(r2, r_d @ r, atol=1e-12)
    assert torch.allclose(p2, (r_d @ p[..., None]).squeeze(-1) + p_d, atol=1e-12)
    conc = se3.draw_local_noise(1, 1000, sigma=0.1, rotation="concentrated", kappa=0.1, generator=gen)
    assert g.geodesic_distance(torch.eye(3), conc.r).mean() < 0.3
    with pytest.raises(ValueError, match="rotation distribution"):
        se3.draw_local_noise(1, 1, 0.1, rotation="gaussian")
