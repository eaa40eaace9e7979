"""Laws of the geodesic blend and of the guided (inpainting) samplers: blends stay on SE(3) and
commute with rigid transforms (componentwise averaging does not), frozen actions end exactly on
the target, zero weights change nothing, and guided SE(3) sampling is equivariant."""

import pytest
import torch

from lerobot_actionflow import geometry as g
from lerobot_actionflow.flow import euclidean, guidance, schedules, se3


def _chunk(b, h, gen, dtype=torch.float64):
    return se3.PoseChunk(
        g.random_rotation(b, h, generator=gen, dtype=dtype),
        torch.randn(b, h, 3, generator=gen, dtype=dtype),
        torch.randn(b, h, generator=gen, dtype=dtype),
    )


def _transform(x: se3.PoseChunk, r_d, p_d) -> se3.PoseChunk:
    return se3.PoseChunk(r_d @ x.r, (r_d @ x.p[..., None]).squeeze(-1) + p_d, x.g)


def _max_diff(a: se3.PoseChunk, b: se3.PoseChunk) -> float:
    return max((u - v).abs().max().item() for u, v in zip(a, b))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_blend_stays_on_se3_and_hits_its_endpoints(dtype):
    gen = torch.Generator().manual_seed(0)
    a, b = _chunk(16, 8, gen, dtype), _chunk(16, 8, gen, dtype)
    s = torch.rand(16, 8, generator=gen, dtype=dtype)
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    assert g.rotation_error(guidance.geodesic_blend(a, b, s).r).max() < tol
    assert _max_diff(guidance.geodesic_blend(a, b, 0.0), a) < tol
    assert _max_diff(guidance.geodesic_blend(a, b, 1.0), b) < 10 * tol
    # halfway along the geodesic: equal angles to both ends
    mid = guidance.geodesic_blend(a, b, 0.5).r
    torch.testing.assert_close(g.geodesic_distance(a.r, mid), g.geodesic_distance(mid, b.r))
    # control: componentwise averaging of matrices leaves SO(3)
    assert g.rotation_error(0.5 * (a.r + b.r)).max() > 0.1


def test_blend_commutes_with_a_rigid_transform_and_quaternion_averaging_does_not():
    gen = torch.Generator().manual_seed(1)
    a, b = _chunk(32, 4, gen), _chunk(32, 4, gen)
    s = torch.rand(32, 4, generator=gen, dtype=torch.float64)
    r_d, p_d = g.random_rotation(generator=gen, dtype=torch.float64), torch.randn(3, generator=gen).double()
    moved = guidance.geodesic_blend(_transform(a, r_d, p_d), _transform(b, r_d, p_d), s)
    assert _max_diff(moved, _transform(guidance.geodesic_blend(a, b, s), r_d, p_d)) < 1e-10

    def quat_average(ra, rb):  # normalised componentwise average of (w >= 0) quaternions
        q = (1 - s[..., None]) * g.matrix_to_quaternion(ra) + s[..., None] * g.matrix_to_quaternion(rb)
        return g.quaternion_to_matrix(q)

    err = (quat_average(r_d @ a.r, r_d @ b.r) - r_d @ quat_average(a.r, b.r)).abs().max()
    assert err > 0.1


def _invariant_field(x: se3.PoseChunk, k: int) -> se3.PoseVelocity:
    """A field that depends on the poses only through invariants (local, chunk-relative)."""
    rel = x.r[:, :1].transpose(-1, -2) @ x.r  # orientation relative to the first action
    v_r = 0.3 * g.log(rel) + 0.1 * (k + 1)
    v_p = (x.r.transpose(-1, -2) @ (x.p[:, :1] - x.p)[..., None]).squeeze(-1) + 0.2
    return se3.PoseVelocity(v_r, v_p, 0.5 - x.g)


def _guide(b, h, d, soft):
    weights = torch.zeros(b, h, dtype=torch.float64)
    weights[:, :d] = 1.0
    weights[:, d : d + len(soft)] = torch.tensor(soft, dtype=torch.float64)
    frozen = torch.zeros(b, h, dtype=torch.bool)
    frozen[:, :d] = True
    return weights, frozen


def test_se3_inpainting_freezes_the_prefix_and_is_equivariant():
    gen = torch.Generator().manual_seed(2)
    x0, target = _chunk(3, 8, gen), _chunk(3, 8, gen)
    times = schedules.uniform_times(4, dtype=torch.float64)
    weights, frozen = _guide(3, 8, 3, [1.0, 0.5])
    x1 = guidance.inpaint_sample(_invariant_field, x0, times, target, weights, frozen)
    assert _max_diff(se3.PoseChunk(*(v[:, :3] for v in x1)), se3.PoseChunk(*(v[:, :3] for v in target))) == 0
    # weight 1 without freezing lands on the target too (the last step aims at it)
    assert _max_diff(se3.PoseChunk(*(v[:, 3] for v in x1)), se3.PoseChunk(*(v[:, 3] for v in target))) < 1e-10
    assert g.rotation_error(x1.r).max() < 1e-10

    r_d, p_d = g.random_rotation(generator=gen, dtype=torch.float64), torch.randn(3, generator=gen).double()
    moved = guidance.inpaint_sample(
        _invariant_field, _transform(x0, r_d, p_d), times, _transform(target, r_d, p_d), weights, frozen
    )
    assert _max_diff(moved, _transform(x1, r_d, p_d)) < 1e-9
    # control: the target left where it was
    x0_moved = _transform(x0, r_d, p_d)
    unmoved = guidance.inpaint_sample(_invariant_field, x0_moved, times, target, weights, frozen)
    assert _max_diff(unmoved, _transform(x1, r_d, p_d)) > 1e-2


def test_se3_inpainting_without_weights_is_plain_euler():
    gen = torch.Generator().manual_seed(3)
    x0, target = _chunk(2, 6, gen), _chunk(2, 6, gen)
    times = schedules.exponential_times(3, dtype=torch.float64)
    weights, frozen = _guide(2, 6, 0, [])
    guided = guidance.inpaint_sample(_invariant_field, x0, times, target, weights, frozen)
    assert _max_diff(guided, se3.euler_sample(_invariant_field, x0, times)) == 0


class _InpaintProgram(torch.nn.Module):
    def __init__(self, frozen_path):
        super().__init__()
        self.frozen_path = frozen_path

    def forward(self, r0, p0, g0, r1, p1, g1, weights, frozen):
        times = schedules.uniform_times(3, dtype=r0.dtype)
        x0, target = se3.PoseChunk(r0, p0, g0), se3.PoseChunk(r1, p1, g1)
        x1 = guidance.inpaint_sample(_invariant_field, x0, times, target, weights, frozen, self.frozen_path)
        return x1.r, x1.p, x1.g


@pytest.mark.parametrize("delay", [0, 2])
def test_the_traceable_frozen_path_gives_the_same_chunk_and_exports(delay):
    """``frozen_path=True`` (what the compiled and exported samplers run) gives the default's
    chunk, with and without frozen actions, and has no data-dependent branch: ``torch.export``
    traces it, and the exported graph gives the same chunk. Control: the default branches on the
    data and does not export."""
    gen = torch.Generator().manual_seed(6)
    x0, target = _chunk(2, 6, gen), _chunk(2, 6, gen)
    weights, frozen = _guide(2, 6, delay, [0.7, 0.3])
    inputs = (*x0, *target, weights, frozen)
    default = se3.PoseChunk(*_InpaintProgram(None)(*inputs))
    traced = se3.PoseChunk(*_InpaintProgram(True)(*inputs))
    assert _max_diff(default, traced) == 0
    exported = torch.export.export(_InpaintProgram(True), inputs, strict=False).module()
    assert _max_diff(se3.PoseChunk(*exported(*inputs)), default) < 1e-12
    with pytest.raises(Exception, match=r"data-dependent|Could not guard"):
        torch.export.export(_InpaintProgram(None), inputs, strict=False)


def test_frozen_actions_follow_the_geodesic_from_the_noise():
    """At every step a frozen action sits on the geodesic from its noise to the target."""
    gen = torch.Generator().manual_seed(4)
    x0, target = _chunk(2, 5, gen), _chunk(2, 5, gen)
    times = schedules.uniform_times(5, dtype=torch.float64)
    weights, frozen = _guide(2, 5, 2, [])
    seen = []

    def field(x, k):
        seen.append(se3.PoseChunk(*(v[:, :2] for v in x)))
        return _invariant_field(x, k)

    guidance.inpaint_sample(field, x0, times, target, weights, frozen)
    for k, x in enumerate(seen):
        on_path = guidance.geodesic_blend(
            se3.PoseChunk(*(v[:, :2] for v in x0)), se3.PoseChunk(*(v[:, :2] for v in target)), times[k]
        )
        assert _max_diff(x, on_path) < 1e-10


def test_euclidean_inpainting():
    gen = torch.Generator().manual_seed(5)
    a0, target = torch.randn(2, 8, 4, generator=gen).double(), torch.randn(2, 8, 4, generator=gen).double()
    times = schedules.exponential_times(4, dtype=torch.float64)

    def field(a, k):
        return torch.tanh(a.flip(1)) - a + 0.1 * k

    weights, frozen = _guide(2, 8, 2, [1.0, 0.5])
    a1 = guidance.inpaint_sample_euclidean(field, a0, times, target, weights, frozen)
    assert torch.equal(a1[:, :2], target[:, :2])
    torch.testing.assert_close(a1[:, 2], target[:, 2])
    free = euclidean.euler_sample(field, a0, times)
    # weight 1/2 on the last step's estimate: the action ends nearer the target than unguided
    assert ((a1[:, 3] - target[:, 3]).norm(dim=-1) < (free[:, 3] - target[:, 3]).norm(dim=-1)).all()
    weights, frozen = _guide(2, 8, 0, [])
    assert torch.equal(guidance.inpaint_sample_euclidean(field, a0, times, target, weights, frozen), free)
