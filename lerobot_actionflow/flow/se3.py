"""Flow matching on SE(3) action poses with a Euclidean gripper channel (App. A, C).

A sample is a :class:`PoseChunk`: ``H`` poses ``(r, p)`` (``(B, H, 3, 3)``, ``(B, H, 3)``) and
gripper values ``g`` (``(B, H)``); a velocity is a :class:`PoseVelocity` ``(v_r, v_p, v_g)`` in
the local frame of each pose. Both keep the order rotation, translation, gripper, like
:mod:`lerobot_actionflow.geometry`.

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
* Midpoint step (second-order Runge-Kutta-Munthe-Kaas in body coordinates): the field at the
  half step ``x_h = euler_step(x, v(x, t), dt / 2)``, ``w = v(x_h, t + dt / 2)`` (in the frame of
  ``x_h``), then ``p <- p + dt r_h w_p`` (``w_p`` is read in the half pose's frame),
  ``r <- r Exp(dt w_r)``, ``g <- g + dt w_g``. Two network calls per step, local error
  ``O(dt^3)``; exact, like Euler, on a constant-body-velocity geodesic field.

Because velocities are local and the noise is drawn in the EEF frame, a network that is
invariant to a global transform ``T`` makes the sampled poses transform by ``T`` (App. C).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import torch

from lerobot_actionflow.geometry import so3


class PoseChunk(NamedTuple):
    """A chunk of poses with a gripper channel.

    Attributes:
        r: rotations ``(B, H, 3, 3)``; p: positions ``(B, H, 3)``; g: gripper values ``(B, H)``.
    """

    r: torch.Tensor
    p: torch.Tensor
    g: torch.Tensor


class PoseVelocity(NamedTuple):
    """Velocities of a :class:`PoseChunk` in the local frame of each pose.

    Attributes:
        r: body angular velocity ``(B, H, 3)``; p: translation velocity ``(B, H, 3)`` in the
            pose's frame (metres per unit flow time); g: gripper velocity ``(B, H)``.
    """

    r: torch.Tensor
    p: torch.Tensor
    g: torch.Tensor


class PathSample(NamedTuple):
    """A point ``x_t`` of the conditional path and its target velocity ``u_t``."""

    x_t: PoseChunk
    u_t: PoseVelocity


#: ``velocity(x, j)``: the field at ``x`` and the ``j``-th flow time at which the solver evaluates
#: it (:func:`lerobot_actionflow.flow.schedules.evaluation_times`; for Euler ``times[j]`` of the
#: grid being integrated). The index (rather than the time) lets a caller precompute the time
#: conditioning of every evaluation once per chunk.
VelocityField = Callable[[PoseChunk, int], PoseVelocity]


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


def noise_to_world(noise: LocalNoise, r_ref: torch.Tensor, p_ref: torch.Tensor) -> PoseChunk:
    """Express local noise in the world: ``(R_e r_loc, p_e + R_e p_loc, g)``.

    Args:
        r_ref, p_ref: reference frames ``(B, 3, 3)``, ``(B, 3)``.
    """
    r = r_ref[:, None] @ noise.r
    p = p_ref[:, None] + (r_ref[:, None] @ noise.p[..., None]).squeeze(-1)
    return PoseChunk(r, p, noise.g)


def geodesic_path(x0: PoseChunk, x1: PoseChunk, t: torch.Tensor) -> PathSample:
    """The conditional path from noise ``x0`` to data ``x1`` at times ``t`` ``(B,)``, and its
    target velocity in the local frame of ``r_t``: ``v_r = Log(r_0^T r_1)``,
    ``v_p = r_t^T (p_1 - p_0)``, ``v_g = g_1 - g_0``."""
    tt = t[:, None]
    v_r = so3.log(x0.r.transpose(-1, -2) @ x1.r)
    r_t = x0.r @ so3.exp(tt[..., None] * v_r)
    dp = x1.p - x0.p
    p_t = x0.p + tt[..., None] * dp
    v_p = (r_t.transpose(-1, -2) @ dp[..., None]).squeeze(-1)
    g_t = x0.g + tt * (x1.g - x0.g)
    return PathSample(PoseChunk(r_t, p_t, g_t), PoseVelocity(v_r, v_p, x1.g - x0.g))


def euler_step(x: PoseChunk, v: PoseVelocity, dt: torch.Tensor | float) -> PoseChunk:
    """One step of Eq. (8) on SE(3) and a Euclidean step on the gripper:
    ``p <- p + r v_p dt``, ``r <- r Exp(v_r dt)``, ``g <- g + v_g dt``; ``dt`` a scalar, or
    ``(B,)`` (one step size per sample)."""
    dt = torch.as_tensor(dt, dtype=x.p.dtype, device=x.p.device)
    dg = dt[:, None] if dt.ndim == 1 else dt
    dp = dg[..., None]
    p = x.p + dp * (x.r @ v.p[..., None]).squeeze(-1)
    r = x.r @ so3.exp(dp * v.r)
    return PoseChunk(r, p, x.g + dg * v.g)


def velocity_between(x: PoseChunk, y: PoseChunk, h: torch.Tensor | float) -> PoseVelocity:
    """The constant local velocity whose Euler step of size ``h`` from ``x`` lands on ``y``:
    ``v_r = Log(r_x^T r_y) / h``, ``v_p = r_x^T (p_y - p_x) / h``, ``v_g = (g_y - g_x) / h``
    (``h`` a scalar, or ``(B,)`` per sample). Only relative quantities: invariant under a rigid
    transform of both poses."""
    h = torch.as_tensor(h, dtype=x.p.dtype, device=x.p.device)
    hg = h[:, None] if h.ndim == 1 else h
    hp = hg[..., None]
    v_r = so3.log(x.r.transpose(-1, -2) @ y.r) / hp
    v_p = (x.r.transpose(-1, -2) @ (y.p - x.p)[..., None]).squeeze(-1) / hp
    return PoseVelocity(v_r, v_p, (y.g - x.g) / hg)


def euler_sample(velocity: VelocityField, x0: PoseChunk, times: torch.Tensor) -> PoseChunk:
    """Integrate the field over the grid ``times`` (``(K + 1,)``, from 0 to 1) by :func:`euler_step`."""
    x = x0
    for k in range(times.shape[0] - 1):
        x = euler_step(x, velocity(x, k), times[k + 1] - times[k])
    return x


def midpoint_step(
    x: PoseChunk, velocity: Callable[[PoseChunk], PoseVelocity], v: PoseVelocity, dt: torch.Tensor | float
) -> PoseChunk:
    """One midpoint step (module docstring) from ``x`` with its velocity ``v``; ``velocity(x_h)``
    evaluates the field at the half-step pose, at the half-step time."""
    half = euler_step(x, v, 0.5 * dt)
    w = velocity(half)
    p = x.p + dt * (half.r @ w.p[..., None]).squeeze(-1)
    r = x.r @ so3.exp(dt * w.r)
    return PoseChunk(r, p, x.g + dt * w.g)


def midpoint_sample(velocity: VelocityField, x0: PoseChunk, times: torch.Tensor) -> PoseChunk:
    """Integrate the field over the grid ``times`` (``(K + 1,)``) by :func:`midpoint_step`:
    ``2K`` calls, ``velocity(x, 2k)`` at ``times[k]`` and ``velocity(x, 2k + 1)`` at the half step."""
    x = x0
    for k in range(times.shape[0] - 1):
        x = midpoint_step(
            x, lambda h, k=k: velocity(h, 2 * k + 1), velocity(x, 2 * k), times[k + 1] - times[k]
        )
    return x


def sample(velocity: VelocityField, x0: PoseChunk, times: torch.Tensor, solver: str = "euler") -> PoseChunk:
    """:func:`euler_sample` or :func:`midpoint_sample`, by ``solver``."""
    if solver == "euler":
        return euler_sample(velocity, x0, times)
    if solver == "midpoint":
        return midpoint_sample(velocity, x0, times)
    raise ValueError(f"unknown solver {solver!r}: expected 'euler' or 'midpoint'")
