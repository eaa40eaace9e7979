"""Sampling a chunk whose beginning is already known (real-time chunking), on SE(3) and in R^n.

A chunk is sampled by Euler steps from flow time ``t = 0`` (noise ``x0``) to ``t = 1`` (data).
Part of it is known: a target chunk ``Y`` (the actions of the previous chunk not yet executed)
with a weight ``s_i`` in ``[0, 1]`` per action, and a boolean ``frozen_i`` marking the actions
that must equal ``Y`` exactly (``frozen`` implies ``s = 1``).

Denoised estimate: from ``x`` at time ``t`` with velocity ``v``, one Euler step to ``t = 1``
lands at ``x1_hat``. Guidance moves ``x1_hat`` toward ``Y`` by the fraction ``s`` and takes the
velocity that lands on that point:

* Euclidean: ``x1_hat = x + (1 - t) v``, ``goal = x1_hat + s (Y - x1_hat)``,
  ``v' = (goal - x) / (1 - t)``.
* SE(3) (local velocities, :mod:`lerobot_actionflow.flow.se3`):
  ``x1_hat = (r Exp((1 - t) v_r), p + (1 - t) r v_p, g + (1 - t) v_g)``, ``goal`` the point at
  ``s`` on the geodesic from ``x1_hat`` to ``Y`` (:func:`geodesic_blend`: rotations along
  ``Exp``/``Log``, never averaged componentwise; positions and gripper linearly), and
  ``v'_r = Log(r^T goal_r) / (1 - t)``, ``v'_p = r^T (goal_p - p) / (1 - t)``,
  ``v'_g = (goal_g - g) / (1 - t)``.

With ``s = 1`` the guided step moves ``x`` along the geodesic toward ``Y``, so an action that
starts on the path from ``x0`` to ``Y`` stays on it. Frozen actions are in addition set to that
path point, ``geodesic_blend(x0, Y, t)``, after every step, and to ``Y`` itself at ``t = 1``.
Actions with ``s = 0`` keep the network's velocity unchanged.

Equivariance: every step is written in left-invariant form (relative rotations ``r^T r'``,
velocities in the local frame, affine blends of positions), so transforming the scene, the
noise frame and ``Y`` by the same rigid transform transforms the sampled chunk by it.

Nothing here imports LeRobot.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from lerobot_actionflow.flow.se3 import PoseChunk, PoseVelocity, VelocityField, euler_step, velocity_between
from lerobot_actionflow.geometry import so3


def geodesic_blend(a: PoseChunk, b: PoseChunk, s: torch.Tensor | float) -> PoseChunk:
    """The point at fraction ``s`` from ``a`` to ``b``: ``r = r_a Exp(s Log(r_a^T r_b))``,
    ``p = p_a + s (p_b - p_a)``, ``g = g_a + s (g_b - g_a)``.

    Args:
        a, b: poses with rotations ``(..., 3, 3)``, positions ``(..., 3)``, gripper ``(...)``.
        s: scalar or ``(...)``; ``s = 0`` gives ``a``, ``s = 1`` gives ``b`` (up to round-off).
    """
    s = torch.as_tensor(s, dtype=a.p.dtype, device=a.p.device)
    w = so3.log(a.r.transpose(-1, -2) @ b.r)
    r = a.r @ so3.exp(s[..., None] * w)
    return PoseChunk(r, a.p + s[..., None] * (b.p - a.p), a.g + s * (b.g - a.g))


def select(mask: torch.Tensor, a: PoseChunk, b: PoseChunk) -> PoseChunk:
    """``a`` where ``mask`` (``(B, H)`` bool), else ``b``."""
    return PoseChunk(
        torch.where(mask[..., None, None], a.r, b.r),
        torch.where(mask[..., None], a.p, b.p),
        torch.where(mask, a.g, b.g),
    )


def denoised_estimate(x: PoseChunk, v: PoseVelocity, t: torch.Tensor) -> PoseChunk:
    """Where one Euler step from ``x`` at time ``t`` to ``t = 1`` lands."""
    return euler_step(x, v, 1 - t)


def velocity_toward(x: PoseChunk, goal: PoseChunk, t: torch.Tensor) -> PoseVelocity:
    """The local velocity whose Euler step from ``x`` at time ``t`` to ``t = 1`` lands on ``goal``."""
    return velocity_between(x, goal, 1 - t)


def guided_velocity(
    x: PoseChunk, v: PoseVelocity, t: torch.Tensor, target: PoseChunk, weights: torch.Tensor
) -> PoseVelocity:
    """``v`` guided toward ``target`` with per-action weights ``(B, H)`` (see module docstring);
    exactly ``v`` where the weight is 0. Needs ``t < 1``."""
    goal = geodesic_blend(denoised_estimate(x, v, t), target, weights)
    guided = velocity_toward(x, goal, t)
    on = weights > 0
    return PoseVelocity(
        torch.where(on[..., None], guided.r, v.r),
        torch.where(on[..., None], guided.p, v.p),
        torch.where(on, guided.g, v.g),
    )


def inpaint_sample(
    velocity: VelocityField,
    x0: PoseChunk,
    times: torch.Tensor,
    target: PoseChunk,
    weights: torch.Tensor,
    frozen: torch.Tensor,
    frozen_path: bool | None = None,
) -> PoseChunk:
    """Euler sampling on SE(3) over ``times`` (``(K + 1,)`` from 0 to 1) with the guidance of the
    module docstring.

    Args:
        velocity: the network's field ``velocity(x, k)``.
        x0: the initial noise in the world frame.
        target: the known chunk ``Y``, same shapes as ``x0`` (entries with weight 0 are unused
            but must be finite).
        weights: ``(B, H)`` in ``[0, 1]``; frozen: ``(B, H)`` bool (weight 1 there).
        frozen_path: set the frozen actions to their path point after every step. None: only when
            some action is frozen (none at no delay: the path's ``Exp``/``Log`` is skipped). The
            result is the same either way; True avoids the data-dependent branch, which a traced
            graph (``torch.compile``, ``torch.export``) cannot hold.
    Returns:
        the chunk at ``t = 1``; its frozen actions are exactly ``target``'s.
    """
    x = x0
    any_frozen = bool(frozen.any()) if frozen_path is None else frozen_path
    for k in range(times.shape[0] - 1):
        t, t_next = times[k], times[k + 1]
        v = guided_velocity(x, velocity(x, k), t, target, weights)
        x = euler_step(x, v, t_next - t)
        if any_frozen:
            x = select(frozen, geodesic_blend(x0, target, t_next), x)
    return select(frozen, target, x)


#: ``velocity(a, k)`` of a Euclidean field (as :data:`lerobot_actionflow.flow.euclidean.VelocityField`).
EuclideanField = Callable[[torch.Tensor, int], torch.Tensor]


def inpaint_sample_euclidean(
    velocity: EuclideanField,
    a0: torch.Tensor,
    times: torch.Tensor,
    target: torch.Tensor,
    weights: torch.Tensor,
    frozen: torch.Tensor,
) -> torch.Tensor:
    """The Euclidean counterpart of :func:`inpaint_sample` on chunks ``(B, H, A)``:
    ``v' = v + s (Y - x1_hat) / (1 - t)`` with ``x1_hat = a + (1 - t) v``; frozen actions follow the
    straight path ``(1 - t) a0 + t Y`` and end exactly at ``Y``."""
    w = weights[..., None].to(a0.dtype)
    mask = frozen[..., None]
    a = a0
    for k in range(times.shape[0] - 1):
        t, t_next = times[k], times[k + 1]
        v = velocity(a, k)
        estimate = a + (1 - t) * v
        v = torch.where(w > 0, v + w * (target - estimate) / (1 - t), v)
        a = a + v * (t_next - t)
        a = torch.where(mask, (1 - t_next) * a0 + t_next * target, a)
    return torch.where(mask, target, a)
