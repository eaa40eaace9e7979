"""Rectified linear flow on flat vectors (App. B, Eq. 5-7).

Path ``a_t = t a_1 + (1 - t) a_0`` from noise ``a_0 ~ N(0, I)`` (``t = 0``) to data ``a_1``
(``t = 1``); target velocity ``u = a_1 - a_0`` (constant along the path); sampling by Euler
steps ``a_{k+1} = a_k + v(a_k, t_k) (t_{k+1} - t_k)`` on a time grid from
:mod:`lerobot_actionflow.flow.schedules`, or midpoint steps
``a_{k+1} = a_k + dt v(a_k + dt/2 v(a_k, t_k), t_k + dt/2)`` (two calls per step).
"""

from __future__ import annotations

from collections.abc import Callable

import torch


def linear_path(a0: torch.Tensor, a1: torch.Tensor, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Point on the path and its target velocity.

    Args:
        a0, a1: ``(B, ...)`` noise and data.
        t: ``(B,)`` times in ``[0, 1]``.
    Returns:
        ``a_t`` and ``u = a_1 - a_0``, both ``(B, ...)``.
    """
    tt = t.reshape(-1, *([1] * (a0.ndim - 1)))
    return tt * a1 + (1 - tt) * a0, a1 - a0


#: ``velocity(a, j)``: the field at ``a (B, ...)`` and the ``j``-th flow time the solver
#: evaluates it at (:func:`lerobot_actionflow.flow.schedules.evaluation_times`), ``(B, ...)`` (the
#: same indexed form as :data:`flow.se3.VelocityField`).
VelocityField = Callable[[torch.Tensor, int], torch.Tensor]


def euler_sample(velocity: VelocityField, a0: torch.Tensor, times: torch.Tensor) -> torch.Tensor:
    """Integrate ``da/dt = v(a, t)`` over the increasing grid ``times`` ``(K + 1,)`` from the
    noise ``a0 (B, ...)``."""
    a = a0
    for k in range(times.shape[0] - 1):
        a = a + velocity(a, k) * (times[k + 1] - times[k])
    return a


def midpoint_sample(velocity: VelocityField, a0: torch.Tensor, times: torch.Tensor) -> torch.Tensor:
    """Integrate by midpoint steps: ``velocity(a, 2k)`` at ``times[k]``, ``velocity(a, 2k + 1)`` at
    the half step (``2K`` calls)."""
    a = a0
    for k in range(times.shape[0] - 1):
        dt = times[k + 1] - times[k]
        a = a + dt * velocity(a + 0.5 * dt * velocity(a, 2 * k), 2 * k + 1)
    return a


def sample(
    velocity: VelocityField, a0: torch.Tensor, times: torch.Tensor, solver: str = "euler"
) -> torch.Tensor:
    """:func:`euler_sample` or :func:`midpoint_sample`, by ``solver``."""
    if solver == "euler":
        return euler_sample(velocity, a0, times)
    if solver == "midpoint":
        return midpoint_sample(velocity, a0, times)
    raise ValueError(f"unknown solver {solver!r}: expected 'euler' or 'midpoint'")
