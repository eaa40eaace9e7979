"""How a policy's action chunks are executed in real time (paper App. G), shared by both policies.

Four options of ``select_action`` (the fields of :class:`RealTimeExecutionConfig`, a base of
both policies' configs); only the guidance toward the previous chunk is on by default:

* **Latency-aware skipping.** A chunk predicted from the observation of step ``n`` holds the
  actions of steps ``n, n + 1, ...`` (it starts at the current step). If the chunk becomes
  available a delay ``D`` after that observation (in control periods: a fixed
  ``execution_delay_steps``, plus ``(execution_delay_s + measured inference time) /
  control_period_s``), the next action the robot can apply is that of step ``n + ceil(D)``:
  actions ``0 .. ceil(D) - 1`` are skipped (:func:`num_skipped`; ``D = 0`` skips none, any
  ``0 < D <= 1`` skips one). A delay that reaches past the chunk's end leaves only its last
  action, which is executed once before the next chunk is planned.
* **Executing ``m`` actions per chunk, then re-planning.** That is each config's
  ``n_action_steps`` (the paper: ``m = 2``); skipping shifts the window, it does not shorten it
  except at the chunk's end (:func:`execution_window`).
* **Exponential smoothing of the commanded target** on SE(3) (:class:`TargetSmoother`):
  ``y_n = geodesic_blend(y_{n-1}, a_n, alpha)``, rotations along the geodesic, positions and
  gripper linearly; ``alpha = 1`` returns the policy's actions unchanged.
* **Guidance toward the previous chunk** (``guide_to_previous_chunk``, :class:`PreviousChunk`):
  each new chunk is sampled with real-time chunking's guidance toward the actions the previous
  chunk still holds from the current step on, so that consecutive chunks agree. Its first
  ``d`` actions (the expected skip) are frozen to the leftover's; at no delay nothing is frozen
  and the guidance alone keeps the plan.

And the inputs of LeRobot's real-time chunking (``lerobot-rollout --inference.type=rtc``)
turned into the target, weights and frozen mask of :mod:`lerobot_actionflow.flow.guidance`
(:func:`rtc_guidance`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from time import perf_counter
from typing import Any

import torch
from lerobot.policies.rtc.configuration_rtc import RTCConfig
from lerobot.policies.rtc.modeling_rtc import RTCProcessor
from lerobot.policies.utils import populate_queues
from torch import Tensor

from lerobot_actionflow.flow.guidance import geodesic_blend
from lerobot_actionflow.flow.se3 import PoseChunk
from lerobot_actionflow.policies.config_errors import require
from lerobot_actionflow.schema import ACTION_DIM
from lerobot_actionflow.schema.tensors import action_to_pose, pose_to_action

#: Delays within this many control periods of a whole number count as that number, so that
#: e.g. 0.08 s at 0.04 s per step is 2 steps, not 3 (0.08 / 0.04 = 2.0000000000000004).
DELAY_ROUNDING = 1e-9


# -- latency-aware skipping -------------------------------------------------------------------------
def num_skipped(delay_steps: float) -> int:
    """Actions of a chunk whose time has passed after a delay of ``delay_steps`` control periods:
    ``ceil(delay_steps)`` (action ``i`` is due ``i`` periods after the observation; it is still
    usable when ``i >= delay_steps``).

    Raises:
        ValueError: a negative or non-finite delay.
    """
    if not math.isfinite(delay_steps) or delay_steps < 0:
        raise ValueError(
            f"the inference delay must be a finite number of control steps >= 0, got {delay_steps}"
        )
    return max(0, math.ceil(delay_steps - DELAY_ROUNDING))


def execution_window(chunk_len: int, skipped: int, n_action_steps: int) -> slice:
    """The actions of a chunk of ``chunk_len`` to execute: ``n_action_steps`` of them from
    ``skipped`` on, cut at the chunk's end; if ``skipped >= chunk_len``, only the last action."""
    if chunk_len < 1 or n_action_steps < 1 or skipped < 0:
        raise ValueError(f"bad execution window: {chunk_len=}, {skipped=}, {n_action_steps=}")
    start = min(skipped, chunk_len - 1)
    return slice(start, min(start + n_action_steps, chunk_len))


@dataclass
class RealTimeExecutionConfig:
    """The real-time execution fields of a policy config (App. G), shared by both flow policies;
    by default nothing is skipped or smoothed, and each chunk after an episode's first is guided
    toward the previous one (with the Euler solver).

    Args:
        execution_delay_steps: a fixed inference delay in control steps; the actions of the new
            chunk that were due during the delay are skipped (a delay ``d`` skips ``ceil(d)``).
        execution_delay_s: a fixed delay in seconds (converted with ``control_period_s``).
        measure_inference_delay: add the measured wall-clock time of each chunk's inference.
        control_period_s: seconds per control step (the paper: 0.04 at 25 Hz); needed for
            delays in seconds.
        target_smoothing [App. G: exponential smoothing]: weight ``alpha`` in (0, 1] of the new
            action in ``y_n = blend(y_{n-1}, a_n, alpha)``, rotations along the SE(3) geodesic;
            1 = no smoothing.
        guide_to_previous_chunk: sample each new chunk with real-time chunking's guidance
            (``predict_action_chunk(inference_delay=d, prev_chunk_left_over=...)``, weights from
            ``rtc_config``, else LeRobot's defaults) toward the previous chunk's actions from the
            current step on (the evidence for the default: benchmarks/RESULTS.md, "Guidance
            toward the previous chunk"); ``d`` is the skip expected from the fixed delay plus the previous
            chunk's measured time. What ``lerobot-rollout --inference.type=rtc`` does, inside
            ``select_action`` (so ``lerobot-eval`` and any loop get it). ActionFlow's compiled
            and exported samplers (``compile_sampler``, ``actionflow-export``) serve the guided
            chunks too. None: on with ``solver="euler"``, off with ``"midpoint"``; True with
            ``"midpoint"`` is refused.

    The paper's "execute two actions, then re-plan" is the policy's ``n_action_steps=2``.
    """

    execution_delay_steps: int = 0
    execution_delay_s: float = 0.0
    measure_inference_delay: bool = False
    control_period_s: float | None = None
    target_smoothing: float = 1.0
    guide_to_previous_chunk: bool | None = None

    def validate_execution(self) -> None:
        """Refuse execution options that cannot work (:class:`PolicyConfigError`)."""
        steps = self.execution_delay_steps
        require(
            isinstance(steps, int) and not isinstance(steps, bool) and steps >= 0,
            f"`execution_delay_steps` must be an integer >= 0, got {steps!r}",
        )
        delay_s = self.execution_delay_s
        require(
            isinstance(delay_s, (int, float)) and math.isfinite(delay_s) and delay_s >= 0,
            f"`execution_delay_s` must be a number of seconds >= 0, got {delay_s!r}",
        )
        period = self.control_period_s
        require(
            period is None or (isinstance(period, (int, float)) and math.isfinite(period) and period > 0),
            f"`control_period_s` must be None or seconds > 0, got {period!r}",
        )
        require(
            period is not None or not (delay_s > 0 or self.measure_inference_delay),
            "`execution_delay_s` > 0 and `measure_inference_delay` need `control_period_s` (seconds "
            "per control step, e.g. 0.05 at 20 Hz) to turn seconds into skipped actions",
        )
        alpha = self.target_smoothing
        require(
            isinstance(alpha, (int, float)) and 0 < alpha <= 1,
            f"`target_smoothing` must be in (0, 1] (1: no smoothing), got {alpha!r}",
        )
        require(
            self.guide_to_previous_chunk is None or isinstance(self.guide_to_previous_chunk, bool),
            f"`guide_to_previous_chunk` must be true, false or null (on with the Euler solver), got "
            f"{self.guide_to_previous_chunk!r}",
        )
        solver = getattr(self, "solver", "euler")
        require(
            self.guide_to_previous_chunk is not True or solver == "euler",
            f"`guide_to_previous_chunk` steers Euler steps, but the policy's solver is {solver!r}: set "
            "--policy.solver=euler (with twice the num_inference_steps for the same network calls)",
        )


def guides_chunks(config: Any) -> bool:
    """Whether ``select_action`` guides each chunk toward the previous one: the config's
    ``guide_to_previous_chunk``, or, when None, whether it samples with Euler steps."""
    flag = getattr(config, "guide_to_previous_chunk", None)
    return getattr(config, "solver", "euler") == "euler" if flag is None else bool(flag)


@dataclass(frozen=True)
class ExecutionOptions:
    """The options of a :class:`RealTimeExecutionConfig`, as ``select_action`` applies them."""

    delay_steps: int = 0
    delay_s: float = 0.0
    measure: bool = False
    control_period_s: float | None = None
    smoothing: float = 1.0
    guide: bool = False

    @classmethod
    def from_config(cls, config: RealTimeExecutionConfig) -> ExecutionOptions:
        return cls(
            delay_steps=config.execution_delay_steps,
            delay_s=config.execution_delay_s,
            measure=config.measure_inference_delay,
            control_period_s=config.control_period_s,
            smoothing=config.target_smoothing,
            guide=guides_chunks(config),
        )

    def delay_in_steps(self, measured_s: float = 0.0) -> float:
        """The delay in control periods: the fixed steps plus the seconds (fixed + measured)
        divided by the control period."""
        seconds = self.delay_s + (measured_s if self.measure else 0.0)
        if seconds == 0:
            return float(self.delay_steps)
        if self.control_period_s is None:
            raise ValueError("a delay in seconds needs `control_period_s` (seconds per control step)")
        return self.delay_steps + seconds / self.control_period_s

    def window(self, chunk_len: int, n_action_steps: int, measured_s: float = 0.0) -> slice:
        """:func:`execution_window` of a chunk that took ``measured_s`` seconds to infer."""
        return execution_window(chunk_len, num_skipped(self.delay_in_steps(measured_s)), n_action_steps)


def timed(fn: Callable[[], Tensor], device: torch.device, measure: bool = True) -> tuple[Tensor, float]:
    """``fn()`` and its wall-clock time in seconds (CUDA work is waited for); 0 if not ``measure``."""
    if not measure:
        return fn(), 0.0
    start = perf_counter()
    out = fn()
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    return out, perf_counter() - start


class PreviousChunk:
    """The last chunk ``select_action`` planned and where the current step is in it, for
    :attr:`RealTimeExecutionConfig.guide_to_previous_chunk`.

    A chunk ``(B, H, A)`` predicted at step ``n`` holds the actions of steps ``n .. n + H - 1``;
    after its window ``start .. stop - 1`` was executed the next observation is that of step
    ``n + stop``, so the leftover is ``chunk[:, stop:]`` (None once the chunk is used up).
    :meth:`reset` at every episode start.
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._chunk: Tensor | None = None
        self._next = 0
        #: measured inference time of the last chunk (s): the estimate of the next one's.
        self.seconds = 0.0

    def store(self, chunk: Tensor, window: slice, seconds: float) -> None:
        self._chunk, self._next, self.seconds = chunk, window.stop, seconds

    def leftover(self) -> Tensor | None:
        """The previous chunk's actions from the current step on ``(B, T, A)``, or None."""
        if self._chunk is None or self._next >= self._chunk.shape[1]:
            return None
        return self._chunk[:, self._next :]


def plan_chunk(
    predict: Callable[..., Tensor],
    history: dict[str, Tensor],
    config: RealTimeExecutionConfig,
    previous: PreviousChunk,
) -> Tensor:
    """One chunk boundary of ``select_action`` with ``config``'s execution options:
    ``predict(history, inference_delay=..., prev_chunk_left_over=...)`` (the policy's
    ``predict_action_chunk`` on a checked history; a leftover only when it guides), timed, and its
    execution window of ``config.n_action_steps``; returns the actions to queue ``(B, m, A)``."""
    options = ExecutionOptions.from_config(config)
    leftover = previous.leftover() if options.guide else None
    delay = num_skipped(options.delay_in_steps(previous.seconds)) if leftover is not None else None
    actions, seconds = timed(
        lambda: predict(history, inference_delay=delay, prev_chunk_left_over=leftover),
        next(iter(history.values())).device,
        options.measure,
    )
    window = options.window(actions.shape[1], config.n_action_steps, seconds)
    previous.store(actions, window, seconds)
    return actions[:, window]


# -- smoothing of the commanded target ----------------------------------------------------------------
class TargetSmoother:
    """Exponential smoothing of absolute EEF targets ``[x, y, z, rot6d, gripper]`` on SE(3).

    ``y_0 = a_0`` and ``y_n = geodesic_blend(y_{n-1}, a_n, alpha)``: the rotation moves the
    fraction ``alpha`` of the way along the geodesic to the new target (``Exp``/``Log``, so ``y``
    stays a rotation and the update commutes with a rigid transform of both inputs), the
    position and gripper move linearly. ``alpha = 1`` is the identity. :meth:`reset` at every
    episode start.
    """

    def __init__(self, alpha: float):
        if not 0 < alpha <= 1:
            raise ValueError(f"smoothing weight alpha must be in (0, 1], got {alpha}")
        self.alpha = alpha
        self._last: Tensor | None = None

    def reset(self) -> None:
        self._last = None

    def __call__(self, action: Tensor) -> Tensor:
        """The smoothed target ``(B, 10)`` for the policy's action ``(B, 10)``."""
        if self.alpha == 1:
            return action
        if action.shape[-1] != ACTION_DIM:
            raise ValueError(
                f"target smoothing needs absolute EEF actions (..., {ACTION_DIM}) [x y z rot6d gripper], "
                f"got shape {tuple(action.shape)}"
            )
        if self._last is None or self._last.shape != action.shape:
            self._last = action
            return action
        # Stored as an action: reading it back through Gram-Schmidt removes round-off drift.
        last, new = PoseChunk(*action_to_pose(self._last)), PoseChunk(*action_to_pose(action))
        blended = geodesic_blend(last, new, self.alpha)
        self._last = pose_to_action(*blended)
        return self._last


# -- real-time chunking --------------------------------------------------------------------------------
@dataclass
class RTCGuidance:
    """What the guided samplers of :mod:`lerobot_actionflow.flow.guidance` need.

    Attributes:
        target: the previous chunk's leftover actions aligned with the new chunk, ``(B, H, A)``
            (zeros where there is none).
        weights: ``(B, H)`` in ``[0, 1]``; frozen: ``(B, H)`` bool, the first
            ``inference_delay`` actions (weight 1).
    """

    target: Tensor
    weights: Tensor
    frozen: Tensor


def leftover_length(leftover: Tensor) -> Tensor:
    """Per batch entry, the number of actions before the trailing all-zero rows ``(B,)``.

    LeRobot's RTC engine pads the leftover chunk with zero actions up to its
    ``execution_horizon``; a zero row is padding (for pose actions it is not even a rotation).
    """
    nonzero = (leftover != 0).any(-1)  # (B, T)
    idx = torch.arange(1, leftover.shape[1] + 1, device=leftover.device)
    return (nonzero * idx).amax(-1) if leftover.shape[1] else torch.zeros(leftover.shape[0], dtype=torch.long)


def rtc_config_of(config: Any) -> RTCConfig | None:
    """The RTC settings ``lerobot-rollout`` stores on the policy config (``rtc_config``), LeRobot's
    defaults if none were set, or None if they are set and disabled."""
    rtc = getattr(config, "rtc_config", None)
    if rtc is None:
        return RTCConfig()
    return rtc if rtc.enabled else None


def rtc_guidance(
    leftover: Tensor,
    inference_delay: int | None,
    horizon: int,
    rtc: RTCConfig,
    batch_size: int,
    execution_horizon: int | None = None,
    offset: int = 0,
) -> RTCGuidance:
    """Align LeRobot's RTC inputs with a chunk of ``horizon`` actions.

    ``leftover`` ``(T, A)`` or ``(B, T, A)``: the previous chunk's actions not executed yet, in
    the space the policy outputs (before the postprocessor), starting at the step of the current
    observation; action ``i`` of the leftover is due at the same step as action ``offset + i`` of
    the chunk being sampled (``offset`` > 0 when the sampled chunk starts at a past step).

    Weights (LeRobot's :meth:`RTCProcessor.get_prefix_weights` with ``rtc``'s
    ``prefix_attention_schedule``): 1 on the first ``d = inference_delay`` actions, which are
    frozen (the robot executes them while the new chunk is inferred), then decaying to 0 at
    ``execution_horizon`` (default ``rtc.execution_horizon``), and 0 past the leftover's end.
    ``d`` is cut to the leftover's length.

    Raises:
        ValueError: a leftover of the wrong shape, non-finite, or a negative delay.
    """
    if leftover.ndim == 2:
        leftover = leftover.unsqueeze(0).expand(batch_size, -1, -1)
    if leftover.ndim != 3 or leftover.shape[0] != batch_size:
        raise ValueError(
            f"prev_chunk_left_over must be (T, A) or (B={batch_size}, T, A), got {tuple(leftover.shape)}"
        )
    if not torch.isfinite(leftover).all():
        raise ValueError("prev_chunk_left_over contains non-finite values (NaN or inf)")
    delay = 0 if inference_delay is None else int(inference_delay)
    if delay < 0:
        raise ValueError(f"inference_delay must be >= 0 control steps, got {inference_delay}")
    space = horizon - offset
    eh = rtc.execution_horizon if execution_horizon is None else int(execution_horizon)
    processor = RTCProcessor(rtc)
    b, t, a = leftover.shape
    target = torch.zeros(b, horizon, a, dtype=leftover.dtype, device=leftover.device)
    n = min(t, space)
    target[:, offset : offset + n] = leftover[:, :n]
    weights = torch.zeros(b, horizon, dtype=leftover.dtype, device=leftover.device)
    frozen = torch.zeros(b, horizon, dtype=torch.bool, device=leftover.device)
    for i, length in enumerate(leftover_length(leftover).tolist()):
        length = min(length, space)
        d = min(delay, length)
        end = max(d, min(eh, length))
        w = processor.get_prefix_weights(d, end, space).to(weights)
        w[length:] = 0
        weights[i, offset:] = w
        frozen[i, offset : offset + d] = True
    return RTCGuidance(target, weights, frozen)


def history_with_step(
    queues: dict[str, deque], step: dict[str, Tensor], action_key: str
) -> dict[str, Tensor]:
    """The observation history ``(B, n_obs_steps, ...)`` after one step ``(B, ...)``, for LeRobot's
    RTC engine, which passes one observation per chunk. ``queues`` (the policy's observation and
    action queues, updated in place) take the step unless it equals the newest one: the engine
    may pass the same observation again, and it must not fill the history twice."""
    newest = {k: q[-1] for k, q in queues.items() if k != action_key and q}
    if len(newest) != len(step) or any(
        newest[k].shape != v.shape or not torch.equal(newest[k], v) for k, v in step.items()
    ):
        queues.update(populate_queues(queues, step))
    return {k: torch.stack(list(q), dim=1) for k, q in queues.items() if k != action_key}
