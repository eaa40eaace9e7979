"""Property tests for SO(3) Exp/Log, hat/vee, geodesics and sampling."""

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lerobot_actionflow import geometry as g

TOL = {torch.float64: 1e-10, torch.float32: 1e-5}
DTYPES = [torch.float64, torch.float32]

unit_vectors = st.tuples(
    st.floats(-1, 1, allow_nan=False), st.floats(-1, 1, allow_nan=False), st.floats(-1, 1, allow_nan=False)
).filter(lambda v: sum(c * c for c in v) > 1e-4)


def axis_angle(axis, angle, dtype):
    a = torch.tensor(axis, dtype=torch.float64)
    a = a / a.norm()
    return (a * angle).to(dtype)


def rotation_from(axis, angle, dtype):
    """Rotation built independently of so3.exp (quaternion formula), in float64."""
    a = torch.tensor(axis, dtype=torch.float64)
    a = a / a.norm()
    q = torch.cat((torch.tensor([math.cos(angle / 2)]), math.sin(angle / 2) * a))
    return g.quaternion_to_matrix(q).to(dtype)


@pytest.mark.parametrize("dtype", DTYPES)
def test_hat_vee_cross_product(dtype):
    gen = torch.Generator().manual_seed(0)
    w = torch.randn(10, 3, generator=gen, dtype=dtype)
    x = torch.randn(10, 3, generator=gen, dtype=dtype)
    assert torch.allclose(g.hat(w) @ x[..., None], torch.linalg.cross(w, x)[..., None], atol=TOL[dtype])
    assert torch.allclose(g.vee(g.hat(w)), w, atol=TOL[dtype])
    assert torch.allclose(g.hat(w), -g.hat(w).transpose(-1, -2))


@settings(max_examples=200, deadline=None)
@given(axis=unit_vectors, angle=st.floats(0, math.pi, allow_nan=False), dtype=st.sampled_from(DTYPES))
def test_exp_of_log_is_identity(axis, angle, dtype):
    r = rotation_from(axis, angle, dtype)
    assert torch.allclose(g.exp(g.log(r)), r, atol=TOL[dtype], rtol=0)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("offset", [0.0, 1e-12, 1e-9, 1e-7, 1e-6, 1e-4, 1e-2])
def test_exp_of_log_near_and_at_pi(dtype, offset):
    gen = torch.Generator().manual_seed(1)
    axes = torch.randn(64, 3, generator=gen, dtype=torch.float64)
    axes = axes / axes.norm(dim=-1, keepdim=True)
    r = g.exp(axes * (math.pi - offset)).to(dtype)
    w = g.log(r)
    assert torch.isfinite(w).all()
    assert torch.allclose(g.exp(w), r, atol=TOL[dtype], rtol=0)
    # The angle is right and the axis is +-the true one (both are valid at exactly pi).
    assert torch.allclose(
        w.norm(dim=-1).double(),
        torch.full((64,), math.pi - offset, dtype=torch.float64),
        atol=TOL[dtype] * 10,
    )
    cos_axis = (w.double() / w.norm(dim=-1, keepdim=True).double() * axes).sum(-1).abs()
    assert torch.allclose(cos_axis, torch.ones(64, dtype=torch.float64), atol=TOL[dtype] * 10)


@pytest.mark.parametrize("dtype", DTYPES)
def test_log_axis_sign_just_below_pi(dtype):
    """Below pi the logarithm is unique: the sign of the axis must be recovered."""
    axes = torch.eye(3, dtype=torch.float64)
    angle = math.pi - (1e-3 if dtype == torch.float32 else 1e-7)
    w = g.log(g.exp(axes * angle).to(dtype))
    assert torch.allclose(w.double(), axes * angle, atol=TOL[dtype] * 100)


@settings(max_examples=200, deadline=None)
@given(axis=unit_vectors, angle=st.floats(0, math.pi - 1e-3, allow_nan=False), dtype=st.sampled_from(DTYPES))
def test_log_of_exp_is_identity(axis, angle, dtype):
    w = axis_angle(axis, angle, dtype)
    assert torch.allclose(g.log(g.exp(w)), w, atol=TOL[dtype], rtol=0)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("scale", [0.0, 1e-12, 1e-8, 1e-5, 1e-3, 2e-3])
def test_exp_log_small_angles_match_series(dtype, scale):
    gen = torch.Generator().manual_seed(2)
    w = torch.randn(32, 3, generator=gen, dtype=dtype) * scale
    r = g.exp(w)
    assert torch.allclose(r, g.exp(w.double()).to(dtype), atol=TOL[dtype])
    assert torch.allclose(g.log(r), w, atol=TOL[dtype], rtol=0)
    assert g.rotation_error(r).max() < TOL[dtype]


@pytest.mark.parametrize("dtype", DTYPES)
def test_exp_matches_matrix_exponential(dtype):
    gen = torch.Generator().manual_seed(3)
    w = torch.randn(50, 3, generator=gen, dtype=torch.float64) * 2
    assert torch.allclose(g.exp(w.to(dtype)).double(), torch.linalg.matrix_exp(g.hat(w)), atol=TOL[dtype])


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 1.0, math.pi - 1e-3, math.pi - 1e-6, math.pi])
def test_gradients_are_finite(angle):
    axis = torch.tensor([0.3, -0.5, 0.8], dtype=torch.float64)
    w = (axis / axis.norm() * angle).requires_grad_(True)
    r = g.exp(w)
    (r * torch.arange(9, dtype=torch.float64).view(3, 3)).sum().backward()
    assert torch.isfinite(w.grad).all()

    r = g.exp(axis / axis.norm() * angle).detach().requires_grad_(True)
    g.log(r).sum().backward()
    assert torch.isfinite(r.grad).all()


def test_exp_gradient_at_zero_is_hat_generator():
    """d Exp(w)/dw at 0 is the hat map: d/dw_i <Exp(w), M> = <hat(e_i), M>."""
    m = torch.randn(3, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    w = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    (g.exp(w) * m).sum().backward()
    expected = torch.stack([(g.hat(e) * m).sum() for e in torch.eye(3, dtype=torch.float64)])
    assert torch.allclose(w.grad, expected, atol=1e-12)


@pytest.mark.parametrize("dtype", DTYPES)
def test_interpolate_endpoints_and_midpoint(dtype):
    gen = torch.Generator().manual_seed(5)
    r0 = g.random_rotation(20, generator=gen, dtype=dtype)
    r1 = g.random_rotation(20, generator=gen, dtype=dtype)
    assert torch.allclose(g.interpolate(r0, r1, 0.0), r0, atol=TOL[dtype] * 10)
    assert torch.allclose(g.interpolate(r0, r1, 1.0), r1, atol=TOL[dtype] * 10)
    t = torch.rand(20, generator=gen, dtype=dtype)
    rt = g.interpolate(r0, r1, t)
    d = g.geodesic_distance(r0, r1)
    # Constant speed along the geodesic.
    assert torch.allclose(g.geodesic_distance(r0, rt), t * d, atol=TOL[dtype] * 100)
    assert torch.allclose(g.geodesic_distance(rt, r1), (1 - t) * d, atol=TOL[dtype] * 100)


def test_random_rotation_is_seeded_uniform_and_preserves_dtype_device():
    a = g.random_rotation(4000, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
    b = g.random_rotation(4000, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
    assert a.dtype == torch.float64 and a.shape == (4000, 3, 3)
    assert torch.equal(a, b)
    assert g.rotation_error(a).max() < 1e-12
    # Haar measure: E[R] = 0 and the angle has density (1 - cos t)/pi, mean pi/2 + 2/pi.
    assert a.mean(0).abs().max() < 0.05
    angle = g.geodesic_distance(torch.eye(3, dtype=torch.float64), a)
    assert abs(angle.mean().item() - (math.pi / 2 + 2 / math.pi)) < 0.03


@pytest.mark.parametrize("dtype", DTYPES)
def test_project_to_so3_fixes_drift_and_reflections(dtype):
    gen = torch.Generator().manual_seed(7)
    r = g.random_rotation(10, generator=gen, dtype=dtype)
    noisy = r + 1e-3 * torch.randn(10, 3, 3, generator=gen, dtype=dtype)
    p = g.project_to_so3(noisy)
    assert g.rotation_error(p).max() < TOL[dtype] * 10
    assert (p - r).abs().max() < 5e-3
    reflection = torch.diag(torch.tensor([1.0, 1.0, -1.0], dtype=dtype))
    assert torch.det(g.project_to_so3(reflection)) > 0


def test_shapes_broadcast_and_errors():
    w = torch.zeros(2, 5, 3)
    assert g.exp(w).shape == (2, 5, 3, 3)
    assert g.log(g.exp(w)).shape == (2, 5, 3)
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        g.exp(torch.zeros(4))
    with pytest.raises(ValueError, match="3, 3"):
        g.log(torch.zeros(2, 4, 4))
