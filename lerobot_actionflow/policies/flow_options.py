"""Validation of the flow-matching options both policy configs share: the training-time
distribution and the ODE solver (:mod:`lerobot_actionflow.flow.schedules`), and the solver's
limits at sampling time."""

from __future__ import annotations

import math
from typing import Any

from lerobot_actionflow.flow.schedules import SOLVERS, TRAIN_TIME_DISTRIBUTIONS
from lerobot_actionflow.flow.shortcut import check_max_steps
from lerobot_actionflow.policies.config_errors import require, require_choice


def validate_train_time_fields(config: Any) -> None:
    """``train_time_distribution`` in :data:`TRAIN_TIME_DISTRIBUTIONS`, ``train_time_beta`` two
    numbers > 0, ``train_time_logit_normal`` a finite ``(mean, std)`` with ``std > 0``."""
    require_choice(config, "train_time_distribution", TRAIN_TIME_DISTRIBUTIONS)
    beta = config.train_time_beta
    require(
        len(beta) == 2 and all(b > 0 for b in beta),
        f"`train_time_beta` must be two numbers > 0, got {beta!r}",
    )
    ln = config.train_time_logit_normal
    require(
        len(ln) == 2 and all(math.isfinite(x) for x in ln) and ln[1] > 0,
        f"`train_time_logit_normal` must be (mean, std) with a finite mean and std > 0, got {ln!r}",
    )


def validate_solver_field(config: Any) -> None:
    """``solver`` in :data:`SOLVERS`."""
    require_choice(config, "solver", SOLVERS)


#: Few-step training objectives (``few_step_objective``).
FEW_STEP_OBJECTIVES = ("none", "shortcut")


def validate_few_step_fields(config: Any) -> None:
    """``few_step_objective`` in :data:`FEW_STEP_OBJECTIVES`, ``shortcut_fraction`` in (0, 1],
    ``shortcut_max_steps`` a power of two >= 2; the shortcut objective samples with the Euler
    solver on the uniform grid (:func:`check_shortcut_sampling`)."""
    require_choice(config, "few_step_objective", FEW_STEP_OBJECTIVES)
    f = config.shortcut_fraction
    require(
        isinstance(f, (int, float)) and not isinstance(f, bool) and 0 < f <= 1,
        f"`shortcut_fraction` must be in (0, 1], got {f!r}",
    )
    try:
        check_max_steps(config.shortcut_max_steps)
    except ValueError:
        require(False, f"`shortcut_max_steps` must be a power of two >= 2, got {config.shortcut_max_steps!r}")
    try:
        check_shortcut_sampling(config)
    except ValueError as e:
        require(False, str(e))


def check_shortcut_sampling(config: Any) -> None:
    """A shortcut model is trained for uniform steps of size ``1/K`` taken by Euler: refuse
    another grid or solver (also at sampling time, since both can change after training)."""
    if config.few_step_objective != "shortcut":
        return
    if config.time_spacing != "uniform":
        raise ValueError(
            f"few_step_objective='shortcut' samples on the uniform time grid (steps of 1/K), got "
            f"time_spacing={config.time_spacing!r}: set --policy.time_spacing=uniform"
        )
    if config.solver != "euler":
        raise ValueError(
            f"few_step_objective='shortcut' takes Euler steps of its conditioned size, got "
            f"solver={config.solver!r}: set --policy.solver=euler"
        )


def check_rtc_solver(solver: str) -> None:
    """Real-time chunking guidance (:mod:`lerobot_actionflow.flow.guidance`) steers Euler steps;
    refuse it with another solver rather than silently integrate differently."""
    if solver != "euler":
        raise ValueError(
            f"real-time chunking (prev_chunk_left_over) integrates with Euler steps, but the policy's "
            f"solver is {solver!r}: set --policy.solver=euler (with twice the num_inference_steps for "
            "the same network calls) to use RTC"
        )
