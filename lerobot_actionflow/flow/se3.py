"""Flow matching on SE(3) action poses with a Euclidean gripper channel (App. A, C).

A sample is a chunk of ``H`` poses ``(r, p)`` (``(B, H, 3, 3)``, ``(B, H, 3)``) and gripper
values ``g`` (``(B, H)``).

* Initial distribution ``q0`` expressed in a reference frame ``(R_e, p_e)`` (the current
  end-effector): ``p_0 = p_e + R_e eps_p`` with ``eps_p ~ N(0, sigma^2 I)``, and ``r_0 = R_e r_loc``
  with ``r_loc`` uniform on SO(3) (or ``Exp(kappa eps_r)``, concentrated around the EEF
  orientation); ``g_0 ~ N(0, 1)``. Drawing the noise in the EEF frame makes it move with the
  scene, which equivariant generation needs.
* Geodesic path: ``r_t = r_0 Exp(t Log(r_0^T r_1))``, ``p_t = (1 - t) p_0 + t p_1``,
  ``g_t = (1 - t) g_0 + t g_1``.
* Target velocities in the local frame of the current pose ``(r_t, p_t)``:
  ``v_r = Log(r_0^T r_1)`` (the body angular velocity, constant along the geodesic) and
  ``v_p = r_t^T (p_1 - p_0)``; ``v_g = g_1 - g_0``.
* Euler step (Eq. 8): ``p <- p + r v_p dt``, ``r <- r Exp(v_r dt)``, ``g <- g + v_g dt``. With
  the exact target velocities a single step from ``t`` to 1 lands on ``(r_1, p_1)``.

Because velocities are local and the noise is drawn in the EEF frame, a network that is
invariant to a global transform ``T`` makes the sampled poses transform by ``T`` (App. C).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from lerobot_actionflow.geometry import so3

#: ``(r_t, p_t, g_t, t) -> (v_p, v_r, v_g)`` with shapes ``(B,H,3), (B,H,3), (B,H)``; ``t`` is ``(B,)``.
VelocityField = Callable[
    [torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor],
    tuple[torch.Tensor, torch.Tensor, torch.Tensor],
]


@dataclass
class LocalNoise:
    """Noise in the reference frame: rotations ``(B, H, 3, 3)``, translations ``(B, H, 3)``,
    gripper ``(B, H)``."""

    r: torch.Tensor
    p: torch.Tensor
    g: torch.Tensor


def draw_local_noise(
    batch_size: int,
    horizon: int,
    sigma: float,
    rotation: str = "uniform",
    kappa: float = 1.0,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> LocalNoise:
    """Draw ``q0`` in the reference (EEF) frame; see the module docstring.

    Args:
        sigma: standard deviation of the translation noise (metres).
        rotation: ``"uniform"`` (Haar on SO(3)) or ``"concentrated"`` (``Exp(kappa eps)``,
            ``eps ~ N(0, I)``, around the reference orientation).
    """
    shape = (batch_size, horizon)
    if rotation == "uniform":
        r = so3.random_rotation(*shape, generator=generator, dtype=dtype, device=device)
    elif rotation == "concentrated":
        r = so3.exp(kappa * torch.randn(*shape, 3, generator=generator, dtype=dtype, device=device))
    else:
        raise ValueError(f"unknown initial rotation distribution {rotation!r}: 'uniform' or 'concentrated'")
    p = sigma * torch.randn(*shape, 3, generator=generator, dtype=dtype, device=device)
    g = torch.randn(*shape, generator=generator, dtype=dtype, device=device)
    return LocalNoise(r, p, g)


def noise_to_world(
    noise: LocalNoise, r_ref: torch.Tensor, p_ref: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Express local noise in the world: ``(R_e r_loc, p_e + R_e p_loc, g)``.

    Args:
        r_ref, p_ref: reference frames ``(B, 3, 3)``, ``(B, 3)``.
    """
    r = r_ref[:, None] @ noise.r
    p = p_ref[:, None] + (r_ref[:, None] @ noise.p[..., None]).squeeze(-1)
    return r, p, noise.g


def geodesic_path(
    r0: torch.Tensor,
    p0: torch.Tensor,
    g0: torch.Tensor,
    r1: torch.Tensor,
    p1: torch.Tensor,
    g1: torch.Tensor,
    t: torch.Tensor,
) -> tuple[tuple[torch.Tensor, torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """The conditional path at time ``t`` and its local target velocities.

    Args:
        r0, p0, g0: noise ``(B, H, 3, 3), (B, H, 3), (B, H)``.
        r1, p1, g1: data, same shapes.
        t: ``(B,)``.
    Returns:
        ``(r_t, p_t, g_t)`` and ``(v_p, v_r, v_g)`` (local frame of ``r_t``).
    """
    tt = t[:, None]
    v_r = so3.log(r0.transpose(-1, -2) @ r1)
    r_t = r0 @ so3.exp(tt[..., None] * v_r)
    dp = p1 - p0
    p_t = p0 + tt[..., None] * dp
    v_p = (r_t.transpose(-1, -2) @ dp[..., None]).squeeze(-1)
    g_t = g0 + tt * (g1 - g0)
    return (r_t, p_t, g_t), (v_p, v_r, g1 - g0)


def euler_step(
    r: torch.Tensor,
    p: torch.Tensor,
    g: torch.Tensor,
    v_p: torch.Tensor,
    v_r: torch.Tensor,
    v_g: torch.Tensor,
    dt: torch.Tensor | float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One step of Eq. (8) on SE(3) and a Euclidean step on the gripper."""
    p = p + dt * (r @ v_p[..., None]).squeeze(-1)
    r = r @ so3.exp(dt * v_r)
    return r, p, g + dt * v_g


def euler_sample(
    velocity: VelocityField,
    r0: torch.Tensor,
    p0: torch.Tensor,
    g0: torch.Tensor,
    times: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Integrate the learned field over the grid ``times`` (``(K + 1,)``, from 0 to 1)."""
    r, p, g = r0, p0, g0
    for k in range(times.shape[0] - 1):
        t = times[k].expand(r.shape[0])
        v_p, v_r, v_g = velocity(r, p, g, t)
        r, p, g = euler_step(r, p, g, v_p, v_r, v_g, times[k + 1] - times[k])
    return r, p, g
