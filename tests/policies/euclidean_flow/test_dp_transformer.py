"""Diffusion-Policy-style transformer: shapes, causal structure, time conditioning."""

import pytest
import torch

from lerobot_actionflow.nn.dp_transformer import DPTransformer, sinusoidal_embedding

H, S, A, D = 6, 2, 3, 5


def _net(**kw):
    torch.manual_seed(0)
    return DPTransformer(A, D, H, S, n_layer=2, n_head=2, n_emb=16, p_drop_attn=0.0, **kw).eval()


def test_shapes_and_defaults():
    net = DPTransformer(10, 20, horizon=16, n_obs_steps=2)
    assert (len(net.decoder.layers), net.n_emb) == (8, 256)  # Diffusion Policy's defaults
    out = _net()(torch.randn(4, H, A), torch.rand(4), torch.randn(4, S, D))
    assert out.shape == (4, H, A)
    with pytest.raises(ValueError, match="expected x"):
        _net()(torch.randn(4, H + 1, A), torch.rand(4), torch.randn(4, S, D))


def test_causal_self_and_cross_attention():
    net = _net()
    x, t, c = torch.randn(1, H, A), torch.rand(1), torch.randn(1, S, D)
    out = net(x, t, c)
    x2 = x.clone()
    x2[:, 3:] += 10.0  # change later actions
    assert torch.allclose(net(x2, t, c)[:, :3], out[:, :3], atol=1e-6)
    assert not torch.allclose(net(x2, t, c)[:, 3:], out[:, 3:], atol=1e-6)
    c2 = c.clone()
    c2[:, 1] += 10.0  # change the observation of step 1: action 0 must not see it
    assert torch.allclose(net(x, t, c2)[:, :1], out[:, :1], atol=1e-6)
    assert not torch.allclose(net(x, t, c2)[:, 1:], out[:, 1:], atol=1e-6)
    # without the causal masks, everything sees everything
    free = _net(causal_attn=False)
    assert not torch.allclose(free(x2, t, c)[:, :3], free(x, t, c)[:, :3], atol=1e-6)


def test_time_changes_the_output():
    net = _net()
    x, c = torch.randn(2, H, A), torch.randn(2, S, D)
    assert not torch.allclose(net(x, torch.zeros(2), c), net(x, torch.full((2,), 0.01), c), atol=1e-5)


def test_sinusoidal_embedding():
    e = sinusoidal_embedding(torch.tensor([0.0, 3.0]), 8)
    assert e.shape == (2, 8)
    assert torch.allclose(e[0], torch.tensor([0.0] * 4 + [1.0] * 4))
    assert torch.allclose(e[1, 0], torch.sin(torch.tensor(3.0)))  # w_0 = 1
    assert torch.allclose(e[1, 3], torch.sin(torch.tensor(3e-4)))  # w_{last} = 1e-4
