"""Invariant Point Attention against a direct transcription of its formula, and its invariance."""

import math

import torch
import torch.nn.functional as F

from lerobot_actionflow import geometry as g
from lerobot_actionflow.nn import InvariantPointAttention, IPASize, SE3InvariantTransformer


def reference_ipa(m: InvariantPointAttention, f, r, p):
    """Alg. 3 with full frames, pair by pair, in the most literal form."""
    b, n, _ = f.shape
    h, c, pq, pv = m.num_heads, m.head_dim, m.num_query_points, m.num_value_points
    scalars, points = m.to_inputs(f).split(m._split, -1)
    q, k, v = scalars.view(b, n, 3, h, c).unbind(2)
    local = points.view(b, n, h, 2 * pq + pv, 3)
    ql, kl, vl = local.split((pq, pq, pv), 3)

    def world(x):  # T_i x for points (B, L, H, P, 3)
        return torch.einsum("blij,blhpj->blhpi", r, x) + p[:, :, None, None, :]

    qw, kw, vw = world(ql), world(kl), world(vl)
    gamma = F.softplus(m.point_weight)
    out = []
    for bi in range(b):
        rows = []
        for i in range(n):
            feats, pts, norms = [], [], []
            for hh in range(h):
                logits = torch.stack(
                    [
                        m.w_l * (q[bi, i, hh] @ k[bi, j, hh])
                        - gamma[hh] * m.w_c / 2 * ((qw[bi, i, hh] - kw[bi, j, hh]) ** 2).sum()
                        for j in range(n)
                    ]
                )
                a = logits.softmax(0)
                feats.append((a[:, None] * v[bi, :, hh]).sum(0))
                ow = (a[:, None, None] * vw[bi, :, hh]).sum(0)  # (P, 3) world
                ol = (r[bi, i].T @ (ow - p[bi, i]).T).T
                pts.append(ol.reshape(-1))
                norms.append(torch.sqrt((ol**2).sum(-1) + 1e-8))
            rows.append(torch.cat((*feats, *pts, *norms)))
        out.append(torch.stack(rows))
    return m.to_out(torch.stack(out))


def _frames(b, n, gen, dtype):
    return g.random_rotation(b, n, generator=gen, dtype=dtype), torch.randn(
        b, n, 3, generator=gen, dtype=dtype
    )


def test_ipa_matches_reference_formula():
    torch.manual_seed(0)
    m = InvariantPointAttention(
        IPASize(dim=12, num_heads=2, head_dim=4, num_query_points=3, num_value_points=2)
    ).double()
    with torch.no_grad():
        m.point_weight.copy_(torch.tensor([0.3, -1.2], dtype=torch.float64))
    gen = torch.Generator().manual_seed(1)
    f = torch.randn(2, 5, 12, generator=gen, dtype=torch.float64)
    r, p = _frames(2, 5, gen, torch.float64)
    assert torch.allclose(m(f, r, p), reference_ipa(m, f, r, p), atol=1e-10)


def test_ipa_mask_blocks_attention():
    torch.manual_seed(0)
    size = IPASize(dim=8, num_heads=2, head_dim=4, num_query_points=2, num_value_points=2)
    m = InvariantPointAttention(size)
    gen = torch.Generator().manual_seed(2)
    f = torch.randn(1, 4, 8, generator=gen)
    r, p = _frames(1, 4, gen, torch.float32)
    mask = torch.ones(4, 4, dtype=torch.bool)
    mask[0, 3] = False  # token 0 does not see token 3
    out = m(f, r, p, mask)
    f2 = f.clone()
    f2[0, 3] += 1.0
    r2, p2 = r.clone(), p.clone()
    p2[0, 3] += 5.0
    out2 = m(f2, r2, p2, mask)
    assert torch.allclose(out[0, 0], out2[0, 0], atol=1e-6)
    assert not torch.allclose(out[0, 1], out2[0, 1], atol=1e-3)


def test_transformer_is_invariant_and_sensitive_to_relative_poses():
    torch.manual_seed(0)
    net = SE3InvariantTransformer(
        IPASize(dim=16, num_heads=2, head_dim=4, num_query_points=2, num_value_points=2), depth=2
    )
    net = net.double()
    gen = torch.Generator().manual_seed(3)
    f = torch.randn(2, 6, 16, generator=gen, dtype=torch.float64)
    cond = torch.randn(2, 16, generator=gen, dtype=torch.float64)
    r, p = _frames(2, 6, gen, torch.float64)
    r_d, p_d = (
        g.random_rotation(generator=gen, dtype=torch.float64),
        3 * torch.randn(3, generator=gen, dtype=torch.float64),
    )
    out = net(f, r, p, cond)
    out_t = net(f, r_d @ r, (r_d @ p[..., None]).squeeze(-1) + p_d, cond)
    assert (out - out_t).abs().max() < 1e-9
    # Moving one token relative to the others must change the output: the check is not vacuous.
    p_moved = p.clone()
    p_moved[:, 2] += 0.5
    assert (net(f, r, p_moved, cond) - out).abs().max() > 1e-3
    r_turned = r.clone()
    r_turned[:, 4] = r_turned[:, 4] @ g.exp(torch.tensor([0.0, 0.0, math.pi / 3], dtype=torch.float64))
    assert (net(f, r_turned, p, cond) - out).abs().max() > 1e-3


def test_cached_context_equals_masked_full_attention():
    """encode_context + forward_with_context is the full transformer in which context tokens
    cannot see the queries and only the queries are time-conditioned."""
    torch.manual_seed(0)
    net = SE3InvariantTransformer(
        IPASize(dim=16, num_heads=2, head_dim=4, num_query_points=2, num_value_points=2), depth=3
    )
    net = net.double()
    gen = torch.Generator().manual_seed(4)
    m, n = 5, 4
    f_ctx = torch.randn(2, m, 16, generator=gen, dtype=torch.float64)
    f_q = torch.randn(2, n, 16, generator=gen, dtype=torch.float64)
    cond = torch.randn(2, 16, generator=gen, dtype=torch.float64)
    r, p = _frames(2, m + n, gen, torch.float64)

    cached = net.forward_with_context(
        f_q, r[:, m:], p[:, m:], cond, net.encode_context(f_ctx, r[:, :m], p[:, :m])
    )

    mask = torch.ones(m + n, m + n, dtype=torch.bool)
    mask[:m, m:] = False
    ctx, q = f_ctx, f_q
    for block in net.blocks:
        f = torch.cat((ctx, q + block.cond(cond)[:, None]), 1)
        f = block._update(f, block.ipa(f, r, p, mask))
        ctx, q = f[:, :m], f[:, m:]
    assert torch.allclose(cached, q, atol=1e-10)
    # The context really is used.
    other = net.forward_with_context(
        f_q, r[:, m:], p[:, m:], cond, net.encode_context(f_ctx + 1.0, r[:, :m], p[:, :m])
    )
    assert (other - cached).abs().max() > 1e-3
