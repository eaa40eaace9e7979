"""Shortcut (self-consistency) targets for few-step sampling on SE(3) x R (after the idea of
shortcut models, Frans et al. 2024).

The network takes, besides the flow time ``t``, the step size ``d`` it will be integrated with:
``v(x, t, d)``, with ``d = 0`` the plain flow-matching field. One step of size ``2d`` should go
where two steps of size ``d`` go:

* ``x' = step(x_t, v(x_t, t, d), d)``, ``x'' = step(x', v(x', t + d, d), d)`` (``step``: the
  SE(3) Euler step of :func:`lerobot_actionflow.flow.se3.euler_step`, with the model's own
  velocities, no gradient);
* target of ``v(x_t, t, 2d)``: the constant local velocity that reaches ``x''`` in time ``2d``,
  ``v_r = Log(r_t^T r'') / (2d)``, ``v_p = r_t^T (p'' - p_t) / (2d)``, ``v_g = (g'' - g_t) / (2d)``
  (:func:`lerobot_actionflow.flow.se3.velocity_between`).

The target composes the two steps on the group; averaging the two local velocities instead is
not the same on SE(3): they live in different frames. Only relative quantities enter, so the
target is invariant under a rigid transform of the scene, like the flow-matching target.

Step sizes: the shortcut step ``2d = 2^-j`` with ``j`` uniform in ``0 .. log2(M) - 1``
(``M = max_steps``, a power of two), so ``d`` runs from ``1/2`` to ``1/M``; ``t = i d`` with ``i``
uniform in ``0 .. 1/d - 2`` (both inner steps end by ``t = 1``). The smallest inner step
``d = 1/M`` uses the flow-matching field (``d = 0``), which anchors the recursion; likewise a
sampler with ``K >= M`` steps conditions on ``d = 0``, and one with ``K < M`` on ``d = 1/K``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

from lerobot_actionflow.flow.se3 import PoseChunk, PoseVelocity, euler_step, velocity_between

#: ``velocity(x, t, d)``: the step-size-conditioned field at ``x``, times ``t (B,)``, step sizes
#: ``d (B,)``.
ConditionedField = Callable[[PoseChunk, torch.Tensor, torch.Tensor], PoseVelocity]


def check_max_steps(max_steps: int) -> int:
    """``max_steps`` must be a power of two >= 2; returns ``log2(max_steps)``."""
    levels = round(math.log2(max_steps)) if isinstance(max_steps, int) and max_steps >= 2 else -1
    if levels < 1 or 2**levels != max_steps:
        raise ValueError(f"shortcut max_steps must be a power of two >= 2, got {max_steps!r}")
    return levels


def draw_shortcut_times(
    n: int, max_steps: int, generator: torch.Generator | None = None, dtype=torch.float32, device=None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Flow times ``t (n,)`` and inner step sizes ``d (n,)`` (module docstring): ``2d = 2^-j``,
    ``t = i d`` with ``t + 2d <= 1``."""
    levels = check_max_steps(max_steps)
    j = torch.randint(0, levels, (n,), generator=generator, device=device)
    cells = 2 ** (j + 1)  # 1 / d
    i = (torch.rand(n, generator=generator, device=device) * (cells - 1)).floor()  # 0 .. 1/d - 2
    d = 1.0 / cells.to(torch.float64)
    return (i.to(torch.float64) * d).to(dtype), d.to(dtype)


def inner_conditioning(d: torch.Tensor, max_steps: int) -> torch.Tensor:
    """The step size the inner steps are conditioned on: ``d``, or 0 at the finest level ``1/M``."""
    return torch.where(d * max_steps <= 1 + 1e-6, torch.zeros_like(d), d)


def sampling_step_size(num_steps: int, max_steps: int) -> float:
    """The step-size conditioning of a ``K``-step uniform sampler: ``1/K`` for ``K < M``, else 0."""
    return 1.0 / num_steps if num_steps < max_steps else 0.0


def shortcut_target(velocity: ConditionedField, x: PoseChunk, t: torch.Tensor, d: torch.Tensor, cond_d=None):
    """The target of ``v(x, t, 2d)``: two Euler steps of size ``d`` with ``velocity`` (conditioned
    on ``cond_d``, default ``d``), composed on the group into one constant velocity over ``2d``.

    Args:
        x: poses at times ``t`` (``r (B, H, 3, 3)``, ``p (B, H, 3)``, ``g (B, H)``).
        t, d: ``(B,)``. Call under ``torch.no_grad()`` for a training target.
    """
    cond_d = d if cond_d is None else cond_d
    x1 = euler_step(x, velocity(x, t, cond_d), d)
    x2 = euler_step(x1, velocity(x1, t + d, cond_d), d)
    return velocity_between(x, x2, 2 * d)
