"""Validation of the flow-matching options both policy configs share: the training-time
distribution and the ODE solver (:mod:`lerobot_actionflow.flow.schedules`), and the solver's
limits at sampling time."""

from __future__ import annotations

import math
from typing import Any

from lerobot_actionflow.flow.schedules import SOLVERS, TRAIN_TIME_DISTRIBUTIONS
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


def check_rtc_solver(solver: str) -> None:
    """Real-time chunking guidance (:mod:`lerobot_actionflow.flow.guidance`) steers Euler steps;
    refuse it with another solver rather than silently integrate differently."""
    if solver != "euler":
        raise ValueError(
            f"real-time chunking (prev_chunk_left_over) integrates with Euler steps, but the policy's "
            f"solver is {solver!r}: set --policy.solver=euler (with twice the num_inference_steps for "
            "the same network calls) to use RTC"
        )
