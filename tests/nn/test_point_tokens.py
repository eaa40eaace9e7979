"""Point-cloud encoders: farthest-point sampling (deterministic, its greedy law, moves with the
scene), k-nearest groups, the invariant group tokens, and the PointNet baseline's symmetries."""

import pytest
import torch

from lerobot_actionflow import geometry as g
from lerobot_actionflow.nn.point_tokens import (
    PointGroupTokenizer,
    farthest_point_indices,
    group_points,
    knn_indices,
)
from lerobot_actionflow.nn.pointnet import PointNetEncoder


def _cloud(seed, b=2, m=40):
    gen = torch.Generator().manual_seed(seed)
    pts = torch.randn(b, m, 3, generator=gen, dtype=torch.float64)
    r = g.random_rotation(generator=gen, dtype=torch.float64)
    return pts, r, torch.randn(3, generator=gen, dtype=torch.float64)


def _greedy_law_holds(pts, idx):
    """Each pick after the first is a farthest point from the picks before it."""
    for b in range(pts.shape[0]):
        for i in range(1, idx.shape[1]):
            d = torch.cdist(pts[b], pts[b, idx[b, :i]]).min(-1).values
            if d[idx[b, i]] < d.max() - 1e-12:
                return False
    return True


def test_fps_is_deterministic_starts_at_row_0_and_follows_its_law():
    pts, _, _ = _cloud(0)
    idx = farthest_point_indices(pts, 10)
    assert (idx[:, 0] == 0).all()
    assert torch.equal(idx, farthest_point_indices(pts.clone(), 10))
    assert len(set(idx[0].tolist())) == 10
    assert _greedy_law_holds(pts, idx)
    # Control: a random subset that starts at row 0 breaks the law.
    assert not _greedy_law_holds(pts, torch.cat((idx[:, :1], torch.arange(1, 10).expand(2, -1)), 1))


def test_fps_and_groups_move_with_a_rigid_motion():
    pts, r, t = _cloud(1)
    moved = pts @ r.T + t
    idx = farthest_point_indices(pts, 12)
    assert torch.equal(idx, farthest_point_indices(moved, 12))
    centres, nbrs = group_points(pts, 12, 5)
    centres_m, nbrs_m = group_points(moved, 12, 5)
    torch.testing.assert_close(centres_m, centres @ r.T + t)
    torch.testing.assert_close(nbrs_m, nbrs @ r.T + t)
    knn = knn_indices(pts, centres, 5)
    assert (knn[..., 0] == idx).all()  # each centre is its own nearest point
    d = (nbrs - centres[:, :, None]).norm(dim=-1)
    assert (d[..., 1:] >= d[..., :-1]).all()  # nearest first
    # every point outside a group is at least as far as the group's farthest member
    all_d = torch.cdist(centres, pts)
    assert (all_d.sort(-1).values[..., 5] >= d[..., -1] - 1e-12).all()


def test_group_tokens_are_invariant_and_their_frames_equivariant():
    pts, r, t = _cloud(2)
    gen = torch.Generator().manual_seed(3)
    r_ref = g.random_rotation(2, generator=gen, dtype=torch.float64)
    torch.manual_seed(0)
    tok = PointGroupTokenizer(8, 6, 16, 12).double()
    f, c = tok(pts, r_ref, 10.0)
    f_m, c_m = tok(pts @ r.T + t, r @ r_ref, 10.0)
    assert f.shape == (2, 8, 12) and c.shape == (2, 8, 3)
    torch.testing.assert_close(f_m, f, atol=1e-10, rtol=0)
    torch.testing.assert_close(c_m, c @ r.T + t)
    # Control: the reference rotation left unrotated (offsets in a frame fixed in the world).
    f_bad, _ = tok(pts @ r.T + t, r_ref, 10.0)
    assert (f_bad - f).abs().max() > 1e-3


def test_sizes_are_checked():
    pts, _, _ = _cloud(4, m=6)
    with pytest.raises(ValueError, match=r"8 centres needs 1\.\.M points, got M=6"):
        farthest_point_indices(pts, 8)
    with pytest.raises(ValueError, match=r"k=7 nearest points need 1\.\.M points, got M=6"):
        knn_indices(pts, pts[:, :2], 7)
    with pytest.raises(ValueError, match=r"shape \(B, M, 3\)"):
        group_points(pts[..., :2], 2, 2)
    with pytest.raises(ValueError, match="group_size must be >= 1"):
        PointGroupTokenizer(4, 0, 8, 8)


def test_pointnet_ignores_point_order_but_not_a_rotation():
    pts, r, _ = _cloud(5)
    torch.manual_seed(0)
    enc = PointNetEncoder(16, 8, scale=10.0).double()
    f = enc(pts)
    assert f.shape == (2, 8)
    torch.testing.assert_close(enc(pts[:, torch.randperm(40)]), f)
    assert (enc(pts @ r.T) - f).abs().max() > 1e-3  # the baseline is not invariant
    assert enc(pts[:, None].expand(2, 3, 40, 3)).shape == (2, 3, 8)  # leading (B, S) dims
