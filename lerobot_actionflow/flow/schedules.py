"""Time grids for Euler sampling and time distributions for training.

Flow time runs from ``t = 0`` (noise) to ``t = 1`` (data), as in the ActionFlow paper.
(LeRobot's openpi-style flow helpers use the opposite direction; they are not used here.)

Exponentially spaced grid (App. E: large steps near ``t = 0``, small steps near ``t = 1``,
where the sample must become precise):

    t_k = (1 - exp(-lambda k / K)) / (1 - exp(-lambda)),   k = 0..K,

so ``dt_k`` shrinks geometrically by ``exp(-lambda / K)`` per step; ``lambda -> 0`` recovers the
uniform grid ``t_k = k / K``.

Training-time distributions (:func:`sample_train_times`): ``U[0, 1]``, ``Beta(a, b)``, and the
logit-normal ``t = sigmoid(z)``, ``z ~ N(mean, std^2)`` (density
``phi((logit t - mean) / std) / (std t (1 - t))``: mean 0 puts the mass at mid-path, a positive
mean moves it toward the data end ``t = 1``).

Solvers (:func:`evaluation_times`): ``"euler"`` evaluates the network once per step, at the
step's start; ``"midpoint"`` twice, at the start and at the half step.
"""

from __future__ import annotations

import math

import torch


def uniform_times(num_steps: int, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """``K + 1`` grid points ``0, 1/K, ..., 1``."""
    _check_steps(num_steps)
    return torch.linspace(0.0, 1.0, num_steps + 1, dtype=dtype, device=device)


def exponential_times(
    num_steps: int, rate: float = 2.0, dtype: torch.dtype = torch.float32, device=None
) -> torch.Tensor:
    """``K + 1`` exponentially spaced grid points from 0 to 1 (see module docstring)."""
    _check_steps(num_steps)
    if not math.isfinite(rate) or rate < 0:
        raise ValueError(f"exponential time grid needs a finite rate >= 0, got {rate}")
    if rate == 0:
        return uniform_times(num_steps, dtype, device)
    k = torch.arange(num_steps + 1, dtype=torch.float64, device=device) / num_steps
    t = (1 - torch.exp(-rate * k)) / (1 - math.exp(-rate))
    t[-1] = 1.0
    return t.to(dtype)


def make_time_grid(
    num_steps: int, spacing: str = "uniform", rate: float = 2.0, dtype=torch.float32, device=None
) -> torch.Tensor:
    """Dispatch on ``spacing`` in ``{"uniform", "exponential"}``."""
    if spacing == "uniform":
        return uniform_times(num_steps, dtype, device)
    if spacing == "exponential":
        return exponential_times(num_steps, rate, dtype, device)
    raise ValueError(f"unknown time spacing {spacing!r}: expected 'uniform' or 'exponential'")


#: Training-time distributions of :func:`sample_train_times`.
TRAIN_TIME_DISTRIBUTIONS = ("uniform", "beta", "logit_normal")
#: ODE solvers of the samplers (``flow.se3.sample``, ``flow.euclidean.sample``).
SOLVERS = ("euler", "midpoint")


def sample_train_times(
    batch_size: int,
    distribution: str = "uniform",
    beta: tuple[float, float] = (1.5, 1.0),
    generator: torch.Generator | None = None,
    dtype=torch.float32,
    device=None,
    logit_normal: tuple[float, float] = (0.0, 1.0),
) -> torch.Tensor:
    """Training times ``(B,)``: ``U[0, 1]``, ``Beta(a, b)`` (``a > b`` favours ``t`` near 1), or
    ``sigmoid(N(mean, std^2))`` with ``logit_normal = (mean, std)`` (in the open interval (0, 1))."""
    if distribution == "logit_normal":
        mean, std = (float(x) for x in logit_normal)
        if not (math.isfinite(mean) and math.isfinite(std) and std > 0):
            raise ValueError(
                f"logit-normal training times need a finite mean and std > 0, got {logit_normal}"
            )
        z = torch.randn(batch_size, generator=generator, dtype=dtype, device=device)
        return torch.sigmoid(mean + std * z)
    if distribution == "uniform":
        return torch.rand(batch_size, generator=generator, dtype=dtype, device=device)
    if distribution == "beta":
        # torch.distributions.Beta takes no generator: it draws from the global RNG, which
        # lerobot-train seeds.
        if generator is not None:
            raise ValueError("Beta training times use the global torch RNG; pass generator=None")
        a, b = (torch.tensor(float(x)) for x in beta)
        return torch.distributions.Beta(a, b).sample((batch_size,)).to(dtype=dtype, device=device)
    raise ValueError(
        f"unknown training time distribution {distribution!r}: expected one of {TRAIN_TIME_DISTRIBUTIONS}"
    )


def evaluation_times(times: torch.Tensor, solver: str = "euler") -> torch.Tensor:
    """The flow times at which a solver evaluates the network over the grid ``times`` ``(K + 1,)``,
    in call order: ``t_0 .. t_{K-1}`` (``"euler"``, ``K`` calls) or
    ``t_0, t_0 + dt_0 / 2, t_1, t_1 + dt_1 / 2, ..`` (``"midpoint"``, ``2K`` calls). A sampler
    precomputes the network's time conditioning for all of them at once."""
    if solver == "euler":
        return times[:-1]
    if solver == "midpoint":
        start = times[:-1]
        return torch.stack((start, 0.5 * (start + times[1:])), -1).reshape(-1)
    raise ValueError(f"unknown solver {solver!r}: expected one of {SOLVERS}")


def network_calls(num_steps: int, solver: str = "euler") -> int:
    """Network evaluations per chunk for ``num_steps`` integration steps: ``K`` or ``2K``."""
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}: expected one of {SOLVERS}")
    return num_steps * (2 if solver == "midpoint" else 1)


def _check_steps(num_steps: int) -> None:
    if not isinstance(num_steps, int) or num_steps < 1:
        raise ValueError(f"the number of integration steps must be an integer >= 1, got {num_steps!r}")
