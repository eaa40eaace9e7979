"""The SE(3) shortcut target: exact on geodesic fields, a composition (not an average) of the two
inner steps, invariant under rigid motions; and its step-size draws."""

import pytest
import torch

from lerobot_actionflow import geometry as g
from lerobot_actionflow.flow import se3, shortcut

F64 = torch.float64


def _chunk(gen, b=4, h=3):
    return se3.PoseChunk(
        g.random_rotation(b, h, generator=gen, dtype=F64),
        torch.randn(b, h, 3, generator=gen, dtype=F64),
        torch.randn(b, h, generator=gen, dtype=F64),
    )


def _geodesic_field(x1):
    """The constant-body-velocity field that reaches ``x1`` at ``t = 1``, whatever ``d``."""
    return lambda x, t, d: se3.velocity_between(x, x1, 1 - t)


def _times(gen, b=4):
    t, d = shortcut.draw_shortcut_times(b, 16, gen, F64)
    return t, d


def test_shortcut_target_of_a_geodesic_field_is_that_field():
    gen = torch.Generator().manual_seed(0)
    x, x1 = _chunk(gen), _chunk(gen)
    t, d = _times(gen)
    field = _geodesic_field(x1)
    target = shortcut.shortcut_target(field, x, t, d)
    exact = field(x, t, 2 * d)
    for a, b in zip(target, exact, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-6)
    # Control: averaging the two local velocities componentwise ignores that the second one is
    # read in the frame of the intermediate pose, and misses the field.
    v1 = field(x, t, d)
    mid = se3.euler_step(x, v1, d)
    v2 = field(mid, t + d, d)
    averaged_p = 0.5 * (v1.p + v2.p)
    assert (averaged_p - exact.p).abs().max() > 1e-3


def test_shortcut_target_is_invariant_under_a_rigid_motion():
    gen = torch.Generator().manual_seed(1)
    x, x1 = _chunk(gen), _chunk(gen)
    t, d = _times(gen)
    r_d, p_d = g.random_rotation(generator=gen, dtype=F64), torch.randn(3, generator=gen, dtype=F64)

    def moved(c):
        return se3.PoseChunk(r_d @ c.r, (r_d @ c.p[..., None]).squeeze(-1) + p_d, c.g)

    def curved(target):
        """An invariant field that is not geodesic: its horizon and gain change with ``t``."""

        def field(x, t, d):
            v = se3.velocity_between(x, target, (1 - t) ** 2 + 0.5)
            gain = (1 + t)[:, None]
            return se3.PoseVelocity(gain[..., None] * v.r, gain[..., None] * v.p, gain * v.g)

        return field

    a = shortcut.shortcut_target(curved(x1), x, t, d)
    b = shortcut.shortcut_target(curved(moved(x1)), moved(x), t, d)
    for u, v in zip(a, b, strict=True):
        torch.testing.assert_close(u, v, rtol=0, atol=1e-9)
    # Control: a world-frame translation target (no r_t^T) turns with the motion.
    x2a = se3.euler_step(x, a, 2 * d)
    x2b = se3.euler_step(moved(x), b, 2 * d)
    world_a = (x2a.p - x.p) / (2 * d)[:, None, None]
    world_b = (x2b.p - moved(x).p) / (2 * d)[:, None, None]
    assert (world_a - world_b).abs().max() > 1e-2


def test_shortcut_times_lie_on_their_step_grid():
    gen = torch.Generator().manual_seed(2)
    t, d = shortcut.draw_shortcut_times(4000, 16, gen, F64)
    assert set((1 / d).round().int().tolist()) == {2, 4, 8, 16}
    assert (t >= 0).all() and (t + 2 * d <= 1 + 1e-12).all()
    torch.testing.assert_close(t / d, (t / d).round(), rtol=0, atol=1e-9)
    cond = shortcut.inner_conditioning(d, 16)
    assert (cond[d == 1 / 16] == 0).all() and (cond[d > 1 / 16] == d[d > 1 / 16]).all()
    assert shortcut.sampling_step_size(2, 16) == 0.5 and shortcut.sampling_step_size(16, 16) == 0.0


@pytest.mark.parametrize("bad", [0, 1, 12, 100, 2.0])
def test_max_steps_must_be_a_power_of_two(bad):
    with pytest.raises(ValueError, match="power of two"):
        shortcut.check_max_steps(bad)
