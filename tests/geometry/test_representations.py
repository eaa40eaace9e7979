"""Round trips between rotation representations, SE(3) group laws, and validation errors."""

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lerobot_actionflow import geometry as g
from lerobot_actionflow.geometry import se3

TOL = {torch.float64: 1e-10, torch.float32: 1e-5}
DTYPES = [torch.float64, torch.float32]

quats = st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda v: sum(c * c for c in v) > 1e-2
)
seeds = st.integers(0, 2**31 - 1)


def random_pose(n, gen, dtype):
    return g.random_rotation(n, generator=gen, dtype=dtype), torch.randn(n, 3, generator=gen, dtype=dtype)


@settings(max_examples=200, deadline=None)
@given(q=quats, dtype=st.sampled_from(DTYPES))
def test_quaternion_round_trip_up_to_sign(q, dtype):
    q = torch.tensor(q, dtype=torch.float64)
    q = (q / q.norm()).to(dtype)
    for qq in (q, -q):
        r = g.quaternion_to_matrix(qq)
        assert g.rotation_error(r) < TOL[dtype]
        back = g.matrix_to_quaternion(r)
        assert back[0] >= 0
        assert torch.allclose(back, q, atol=TOL[dtype]) or torch.allclose(back, -q, atol=TOL[dtype])
        assert torch.allclose(g.quaternion_to_matrix(back), r, atol=TOL[dtype])


@pytest.mark.parametrize("dtype", DTYPES)
def test_matrix_to_quaternion_at_pi_rotations(dtype):
    """Zero trace-plus-one is where naive formulas divide by zero."""
    for axis in torch.eye(3, dtype=torch.float64):
        r = g.exp(axis * math.pi).to(dtype)
        q = g.matrix_to_quaternion(r)
        assert torch.allclose(q.abs(), torch.cat((torch.zeros(1), axis)).to(dtype), atol=TOL[dtype])


def test_scalar_first_and_last_conversions():
    q_wxyz = torch.tensor([0.1, 0.2, 0.3, 0.4])
    q_xyzw = g.wxyz_to_xyzw(q_wxyz)
    assert q_xyzw.tolist() == pytest.approx([0.2, 0.3, 0.4, 0.1])
    assert torch.equal(g.xyzw_to_wxyz(q_xyzw), q_wxyz)


def test_quaternion_multiply_matches_matrix_product():
    gen = torch.Generator().manual_seed(0)
    q1 = torch.randn(20, 4, generator=gen, dtype=torch.float64)
    q2 = torch.randn(20, 4, generator=gen, dtype=torch.float64)
    q1, q2 = q1 / q1.norm(dim=-1, keepdim=True), q2 / q2.norm(dim=-1, keepdim=True)
    lhs = g.quaternion_to_matrix(g.quaternion_multiply(q1, q2))
    assert torch.allclose(lhs, g.quaternion_to_matrix(q1) @ g.quaternion_to_matrix(q2), atol=1e-12)


def test_quaternion_of_known_rotation():
    # 90 degrees about z: (cos 45, 0, 0, sin 45), maps x to y.
    r = g.quaternion_to_matrix(torch.tensor([math.sqrt(0.5), 0, 0, math.sqrt(0.5)], dtype=torch.float64))
    assert torch.allclose(
        r @ torch.tensor([1.0, 0, 0], dtype=torch.float64), torch.tensor([0.0, 1, 0], dtype=torch.float64)
    )


@settings(max_examples=100, deadline=None)
@given(seed=seeds, dtype=st.sampled_from(DTYPES))
def test_axis_angle_round_trip(seed, dtype):
    gen = torch.Generator().manual_seed(seed)
    r = g.random_rotation(16, generator=gen, dtype=dtype)
    axis, angle = g.matrix_to_axis_angle(r)
    assert torch.allclose(axis.norm(dim=-1), torch.ones(16, dtype=dtype), atol=TOL[dtype])
    assert ((angle >= 0) & (angle <= math.pi + TOL[dtype])).all()
    assert torch.allclose(g.axis_angle_to_matrix(axis, angle), r, atol=TOL[dtype] * 10)


@settings(max_examples=100, deadline=None)
@given(seed=seeds, dtype=st.sampled_from(DTYPES))
def test_rotation_6d_round_trip(seed, dtype):
    gen = torch.Generator().manual_seed(seed)
    r = g.random_rotation(16, generator=gen, dtype=dtype)
    d6 = g.matrix_to_rotation_6d(r)
    assert d6.shape == (16, 6)
    assert torch.allclose(g.rotation_6d_to_matrix(d6), r, atol=TOL[dtype])
    # Gram-Schmidt is invariant to scaling each column and to adding b1 to the second column.
    skewed = torch.cat((3.0 * d6[:, :3], 0.5 * d6[:, 3:] + 0.7 * d6[:, :3]), -1)
    assert torch.allclose(g.rotation_6d_to_matrix(skewed), r, atol=TOL[dtype] * 10)


@settings(max_examples=100, deadline=None)
@given(seed=seeds, dtype=st.sampled_from(DTYPES))
def test_se3_group_laws(seed, dtype):
    gen = torch.Generator().manual_seed(seed)
    a, b, c = (random_pose(8, gen, dtype) for _ in range(3))
    tol = TOL[dtype] * 10
    # Associativity.
    ab_c = se3.compose(*se3.compose(*a, *b), *c)
    a_bc = se3.compose(*a, *se3.compose(*b, *c))
    assert all(torch.allclose(x, y, atol=tol) for x, y in zip(ab_c, a_bc))
    # Inverse and identity.
    r, p = se3.compose(*a, *se3.inverse(*a))
    assert torch.allclose(r, torch.eye(3, dtype=dtype).expand_as(r), atol=tol)
    assert torch.allclose(p, torch.zeros_like(p), atol=tol)
    eye = (torch.eye(3, dtype=dtype).expand(8, 3, 3), torch.zeros(8, 3, dtype=dtype))
    assert all(torch.allclose(x, y, atol=tol) for x, y in zip(se3.compose(*eye, *a), a))
    # Action on points is compatible with composition, and matches 4x4 matrices.
    x = torch.randn(8, 3, generator=gen, dtype=dtype)
    assert torch.allclose(se3.apply(*se3.compose(*a, *b), x), se3.apply(*a, se3.apply(*b, x)), atol=tol)
    m = se3.to_matrix(*a) @ se3.to_matrix(*b)
    assert all(torch.allclose(u, v, atol=tol) for u, v in zip(se3.from_matrix(m), se3.compose(*a, *b)))
    assert all(torch.allclose(u, v, atol=tol) for u, v in zip(se3.relative(*a, *se3.compose(*a, *b)), b))


def test_pose_layouts_round_trip():
    gen = torch.Generator().manual_seed(1)
    r, p = random_pose(5, gen, torch.float64)
    for to, back in ((se3.rp_to_pose7, se3.pose7_to_rp), (se3.rp_to_pose9, se3.pose9_to_rp)):
        r2, p2 = back(to(r, p))
        assert torch.allclose(r2, r, atol=1e-12) and torch.equal(p2, p)
    with pytest.raises(ValueError, match="qw"):
        se3.pose7_to_rp(torch.zeros(5, 9))


def test_geometry_preserves_dtype_device_and_batch():
    for dtype in DTYPES:
        w = torch.zeros(2, 3, 3, dtype=dtype)
        for out in (
            g.exp(w),
            g.log(g.exp(w)),
            g.matrix_to_quaternion(g.exp(w)),
            g.matrix_to_rotation_6d(g.exp(w)),
        ):
            assert out.dtype == dtype and out.device == w.device and out.shape[:2] == (2, 3)


def test_check_rotation_matrix_names_the_bad_index():
    gen = torch.Generator().manual_seed(2)
    r = g.random_rotation(4, 3, generator=gen, dtype=torch.float64)
    drift = r + 1e-6
    fixed = g.check_rotation_matrix(drift, name="observation.poses")
    assert g.rotation_error(fixed).max() < 1e-12

    bad = r.clone()
    bad[2, 1] = bad[2, 1] * 1.5
    with pytest.raises(ValueError, match=r"observation\.poses\[2, 1\] is not a rotation matrix"):
        g.check_rotation_matrix(bad, name="observation.poses")
    reflection = r.clone()
    reflection[0, 0] = -reflection[0, 0]
    with pytest.raises(ValueError, match=r"rotation\[0, 0\] is not a rotation"):
        g.check_rotation_matrix(reflection)
    nan = r.clone()
    nan[3, 2, 0, 0] = float("nan")
    with pytest.raises(ValueError, match=r"rotation\[3, 2\] is not finite"):
        g.check_rotation_matrix(nan)
    with pytest.raises(ValueError, match="shape"):
        g.check_rotation_matrix(torch.zeros(3, 4))


def test_check_quaternion():
    q = torch.tensor([[1.0, 0, 0, 0], [0.0, 0.6, 0.8, 0.0]])
    assert torch.allclose(g.check_quaternion(q * 1.0001), q, atol=1e-6)
    with pytest.raises(ValueError, match=r"quat\[1\] is not a unit quaternion: norm 2"):
        g.check_quaternion(torch.stack((q[0], 2 * q[1])), name="quat")
    with pytest.raises(ValueError, match=r"quaternion\[0\] is not finite"):
        g.check_quaternion(torch.tensor([[float("inf"), 0, 0, 0]]))
    with pytest.raises(ValueError, match=r"x\[1\] is not finite"):
        g.check_finite(torch.tensor([[0.0, 1.0], [float("nan"), 0.0]]), name="x")
