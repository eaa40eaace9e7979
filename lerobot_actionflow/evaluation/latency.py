"""Latency-honest evaluation: the environment keeps stepping while the policy infers.

LeRobot's ``rollout`` (``lerobot_eval``) calls ``policy.select_action`` once per env step; a
policy computes a new chunk only when its action queue is empty, and that is when inference
time passes. :class:`ChunkLatency` hooks ``select_action`` (and ``reset``) of a policy: at each
such chunk boundary, for a latency ``L`` seconds (injected, or the measured wall-clock time of
that call) and a control period ``dt``, it tells the envs (:class:`LatencyHoldWrapper`, through
``set_attr``) to advance ``k = ceil(L / dt)`` control steps (:func:`hold_steps`, the same
rounding as the policies' latency-aware skipping) before the action just returned takes effect.
So a chunk predicted from the observation of step ``n`` has its first applied action at step
``n + k``; the steps ``n .. n + k - 1`` hold the previous commanded target.

Modes (:data:`MODES`):

* ``plain``: the policy as trained; its chunk starts ``k`` steps late (any policy, LeRobot's
  ``diffusion`` included).
* ``scheme``: the paper's execution scheme (App. G) on a flow policy, configured by
  :func:`configure_execution`: latency-aware skipping of ``k`` actions (the same ``L`` and
  ``dt``, so the policy's skip equals the env's hold; with a measured latency the policy times
  its own network call, a sub-interval of the hook's), ``m`` actions per chunk and exponential
  smoothing of the target.
* ``rtc``: simulated real-time chunking for a policy whose ``supports_rtc()``: the hook keeps the
  current chunk itself and, at each boundary, calls ``predict_action_chunk(obs,
  inference_delay=d, prev_chunk_left_over=leftover)`` with the previous chunk's actions from the
  current step on; during the ``k`` steps of the delay the envs execute the leftover's first
  ``k`` actions (what a robot does while the next chunk is computed; the previous target once
  the leftover is used up), then the new chunk's actions ``k .. k + m - 1``. ``d = k`` for an
  injected latency; with a measured one, ``d`` is the previous chunk's measured ``k`` (the
  estimate LeRobot's RTC engine also has to use). No threads are involved, so the result is
  reproducible; this stands in for ``lerobot-rollout --inference.type=rtc``, which needs a
  real-time robot. With ``n_obs_steps > 1`` each observation between boundaries enters the
  policy's history through its ``_observation_history`` (actionflow, euclidean_flow).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from time import perf_counter
from typing import Any

import numpy as np
import torch
from torch import Tensor

from lerobot_actionflow.envs.progress import MIN_JOINT_MARGIN, NEAR_JOINT_LIMIT_RAD, SUBGOALS_REACHED
from lerobot_actionflow.policies.execution import execution_window, num_skipped
from lerobot_actionflow.schema import ACTION_KEY

MODES = ("plain", "scheme", "rtc")
FLOW_POLICIES = ("actionflow", "euclidean_flow")


def hold_steps(latency_s: float, control_period_s: float) -> int:
    """Control steps that pass during an inference of ``latency_s`` seconds: ``ceil(L / dt)``
    (:func:`~lerobot_actionflow.policies.execution.num_skipped`; 0 for ``L = 0``)."""
    period = control_period_s
    if not (isinstance(period, (int, float)) and math.isfinite(period) and period > 0):
        raise ValueError(f"the control period must be seconds > 0, got {control_period_s!r}")
    if not (isinstance(latency_s, (int, float)) and math.isfinite(latency_s) and latency_s >= 0):
        raise ValueError(f"the latency must be seconds >= 0, got {latency_s!r}")
    return num_skipped(latency_s / control_period_s)


@dataclass(frozen=True)
class Scheme:
    """The paper's execution scheme: ``m`` actions per chunk, smoothing weight ``alpha``."""

    action_steps: int = 2
    smoothing: float = 0.5


def configure_execution(
    policy,
    mode: str,
    latency_s: float | None,
    control_period_s: float,
    scheme: Scheme,
    trained_action_steps: int,
) -> None:
    """Set the execution fields of ``policy.config`` for one evaluation cell.

    ``plain`` / ``rtc``: no skipping, no smoothing, the trained ``n_action_steps`` (``rtc``
    re-plans after as many). ``scheme``: skip from ``latency_s`` (``None``: the measured time),
    ``scheme.action_steps`` per chunk, smoothing ``scheme.smoothing``. No mode lets
    ``select_action`` guide toward the previous chunk (``guide_to_previous_chunk``, whatever the
    checkpoint's config says): ``rtc`` guides in its own loop. Takes effect at the next
    ``policy.reset()`` (LeRobot's rollout calls it).

    Raises:
        ValueError: an unknown mode, ``scheme``/``rtc`` on a policy without those options.
    """
    if mode not in MODES:
        raise ValueError(f"unknown latency mode {mode!r}; choose one of {MODES}")
    cfg = policy.config
    if mode == "rtc" and not policy.supports_rtc():
        raise ValueError(f"policy type {cfg.type!r} does not support real-time chunking (supports_rtc)")
    if cfg.type not in FLOW_POLICIES:
        if mode == "scheme":
            raise ValueError(f"the execution scheme needs a flow policy {FLOW_POLICIES}, got {cfg.type!r}")
        cfg.n_action_steps = trained_action_steps
        return
    scheme_on = mode == "scheme"
    cfg.n_action_steps = min(scheme.action_steps, cfg.horizon) if scheme_on else trained_action_steps
    cfg.target_smoothing = scheme.smoothing if scheme_on else 1.0
    cfg.execution_delay_steps = 0
    cfg.execution_delay_s = float(latency_s or 0.0) if scheme_on else 0.0
    cfg.measure_inference_delay = scheme_on and latency_s is None
    cfg.control_period_s = control_period_s
    cfg.guide_to_previous_chunk = False
    cfg.validate_execution()


class ChunkLatency:
    """Hooks a policy's ``select_action`` and ``reset`` so that each chunk costs env time.

    Args:
        policy: a LeRobot policy with an action queue ``policy._queues["action"]`` (actionflow,
            euclidean_flow, diffusion, ...).
        vec_env: the vector env of :class:`LatencyHoldWrapper` envs that the rollout steps.
        control_period_s: seconds per env step.
        latency_s: injected latency per chunk, or ``None`` to use the measured time of each call.
        rtc: simulated real-time chunking (see the module docstring).
        to_env_action: policy-space actions ``(N, A)`` -> env actions ``(N, A)`` (the policy's and
            the env's postprocessors); needed for ``rtc``, whose held actions bypass the rollout.

    Attributes:
        holds: the ``k`` of every chunk boundary since construction.
    """

    def __init__(
        self,
        policy,
        vec_env,
        control_period_s: float,
        latency_s: float | None = 0.0,
        rtc: bool = False,
        to_env_action: Callable[[Tensor], np.ndarray] | None = None,
    ):
        hold_steps(0.0 if latency_s is None else latency_s, control_period_s)  # validates both
        if rtc:
            if not policy.supports_rtc():
                raise ValueError(f"policy type {policy.config.type!r} does not support real-time chunking")
            if policy.config.n_obs_steps > 1 and not hasattr(policy, "_observation_history"):
                raise ValueError(
                    f"simulated RTC with n_obs_steps={policy.config.n_obs_steps} needs the policy's "
                    "`_observation_history` (actionflow, euclidean_flow) to keep its history"
                )
            if to_env_action is None:
                raise ValueError("simulated RTC needs to_env_action (postprocessing of the held actions)")
        elif not hasattr(policy, "_queues") or ACTION_KEY not in policy._queues:
            raise ValueError(
                f"policy type {policy.config.type!r} has no action queue `_queues[{ACTION_KEY!r}]`: "
                "cannot tell its chunk boundaries"
            )
        self.policy, self.vec_env = policy, vec_env
        self.control_period_s, self.latency_s, self.rtc = control_period_s, latency_s, rtc
        self.to_env_action = to_env_action
        self.holds: list[int] = []
        self._select, self._reset = policy.select_action, policy.reset
        self._rtc_reset()

    # -- install / remove -------------------------------------------------------------------------
    def __enter__(self) -> ChunkLatency:
        self.policy.select_action = self.select_action
        self.policy.reset = self.reset
        return self

    def __exit__(self, *exc) -> None:
        del self.policy.select_action, self.policy.reset  # back to the class's methods

    # -- hooked methods ---------------------------------------------------------------------------
    def reset(self) -> None:
        self._reset()
        self._rtc_reset()

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs: Any) -> Tensor:
        if self.rtc:
            return self._select_rtc(batch)
        boundary = len(self.policy._queues[ACTION_KEY]) == 0
        start = perf_counter()
        action = self._select(batch, **kwargs)
        if boundary:
            k = self._hold(perf_counter() - start)
            self.vec_env.set_attr("pending_hold", [k] * self.vec_env.num_envs)
        return action

    # -- internals --------------------------------------------------------------------------------
    def _hold(self, measured_s: float) -> int:
        k = hold_steps(measured_s if self.latency_s is None else self.latency_s, self.control_period_s)
        self.holds.append(k)
        return k

    def _rtc_reset(self) -> None:
        self._queue: deque[Tensor] = deque()
        self._chunk: Tensor | None = None
        self._pos = 0  # index in _chunk of the step of the next observation
        self._estimate = 0  # inference_delay given with a measured latency

    def _select_rtc(self, batch: dict[str, Tensor]) -> Tensor:
        if self._queue:
            if self.policy.config.n_obs_steps > 1:  # every observation enters the history
                self.policy._observation_history(batch)
            return self._queue.popleft()
        horizon = self._chunk.shape[1] if self._chunk is not None else None
        leftover = self._chunk[:, self._pos :] if horizon is not None and self._pos < horizon else None
        if self.latency_s is not None:
            delay = hold_steps(self.latency_s, self.control_period_s)
        else:
            delay = self._estimate
        start = perf_counter()
        chunk = self.policy.predict_action_chunk(
            batch,
            inference_delay=delay if leftover is not None else None,
            prev_chunk_left_over=leftover,
        )
        k = self._hold(perf_counter() - start)
        self._estimate = k
        n = self.vec_env.num_envs
        if leftover is None or k == 0:
            holds: list = [k] * n
        else:
            played = leftover[:, :k]  # (B, <=k, A): executed while the new chunk is inferred
            b, t, a = played.shape
            env_actions = np.asarray(self.to_env_action(played.reshape(b * t, a))).reshape(b, t, -1)
            if t < k:  # leftover used up: hold its last target
                env_actions = np.concatenate([env_actions, np.repeat(env_actions[:, -1:], k - t, axis=1)], 1)
            holds = [env_actions[i] for i in range(n)]
        self.vec_env.set_attr("pending_hold", holds)
        window = execution_window(chunk.shape[1], k, self.policy.config.n_action_steps)
        self._chunk, self._pos = chunk, k + (window.stop - window.start)
        self._queue.extend(chunk[:, window].transpose(0, 1))
        return self._queue.popleft()


def postprocess_actions(postprocessor, env_postprocessor) -> Callable[[Tensor], np.ndarray]:
    """Policy-space actions ``(N, A)`` -> env actions ``(N, A)``, as LeRobot's rollout does it."""

    def to_env_action(actions: Tensor) -> np.ndarray:
        out = env_postprocessor({ACTION_KEY: postprocessor(actions)})[ACTION_KEY]
        return out.to("cpu").numpy()

    return to_env_action


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Success rate and smoothness over episode records (:class:`LatencyHoldWrapper`): the mean
    and the largest of the per-episode largest jumps, the mean jerk, mean held steps per chunk;
    and, where the records hold the episodes' progress, :func:`summarize_progress`."""
    if not records:
        return {"n_episodes": 0, "pc_success": float("nan")}
    col = {
        k: np.array([r[k] for r in records], dtype=np.float64)
        for k in records[0]
        if k not in ("seed", SUBGOALS_REACHED)
    }
    chunks = max(col["chunks"].sum(), 1.0)
    return {
        **summarize_progress(records),
        "n_episodes": len(records),
        "pc_success": 100.0 * float(col["success"].mean()),
        "mean_max_position_jump_m": float(col["max_position_jump_m"].mean()),
        "max_position_jump_m": float(col["max_position_jump_m"].max()),
        "mean_max_rotation_jump_rad": float(col["max_rotation_jump_rad"].mean()),
        "max_rotation_jump_rad": float(col["max_rotation_jump_rad"].max()),
        "mean_jerk_m2": float(col["jerk_m2"].mean()),
        "mean_control_steps": float(col["control_steps"].mean()),
        "held_steps_per_chunk": float(col["held_steps"].sum() / chunks),
    }


def summarize_progress(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Where the episodes got to (:mod:`lerobot_actionflow.envs.progress`): ``pc_subgoals``,
    ``{name: % of episodes that reached it}`` in task order; ``pc_near_joint_limit``, the % of
    episodes in which an arm joint came within :data:`NEAR_JOINT_LIMIT_RAD` of its limit, over
    all episodes and over the failed ones (``pc_near_joint_limit_failed``, NaN without failures);
    the mean of the episodes' smallest joint margins (``mean_min_joint_margin_rad``). ``{}`` for
    records without progress."""
    if not records or MIN_JOINT_MARGIN not in records[0]:
        return {}
    names = list(records[0][SUBGOALS_REACHED])
    reached = {n: np.array([r[SUBGOALS_REACHED][n] for r in records], dtype=bool) for n in names}
    margin = np.array([r[MIN_JOINT_MARGIN] for r in records], dtype=np.float64)
    near = margin < NEAR_JOINT_LIMIT_RAD
    failed = ~np.array([r["success"] for r in records], dtype=bool)
    return {
        "pc_subgoals": {n: 100.0 * float(hits.mean()) for n, hits in reached.items()},
        "pc_near_joint_limit": 100.0 * float(near.mean()),
        "pc_near_joint_limit_failed": 100.0 * float(near[failed].mean()) if failed.any() else float("nan"),
        "mean_min_joint_margin_rad": float(margin.mean()),
    }


def evaluate_with_latency(
    policy,
    vec_env,
    env_preprocessor,
    env_postprocessor,
    preprocessor,
    postprocessor,
    *,
    control_period_s: float,
    latency_s: float | None,
    rtc: bool,
    n_episodes: int,
    start_seed: int,
) -> dict[str, Any]:
    """LeRobot's ``eval_policy`` on ``vec_env`` (:func:`make_latency_envs`) with the policy
    hooked by :class:`ChunkLatency`. Returns :func:`summarize` of the episodes, the per-episode
    records (``episodes``, in seed order) and LeRobot's own success rate (``lerobot_pc_success``,
    which must agree)."""
    from lerobot.scripts.lerobot_eval import eval_policy

    vec_env.call("pop_episode_records")  # forget episodes of earlier evaluations
    hook = ChunkLatency(
        policy,
        vec_env,
        control_period_s,
        latency_s=latency_s,
        rtc=rtc,
        to_env_action=postprocess_actions(postprocessor, env_postprocessor) if rtc else None,
    )
    with hook, torch.no_grad():
        info = eval_policy(
            vec_env,
            policy,
            env_preprocessor,
            env_postprocessor,
            preprocessor,
            postprocessor,
            n_episodes=n_episodes,
            start_seed=start_seed,
        )
    by_seed = {r["seed"]: r for env_records in vec_env.call("pop_episode_records") for r in env_records}
    episodes = [by_seed[ep["seed"]] for ep in info["per_episode"] if ep["seed"] in by_seed]
    return {
        **summarize(episodes),
        "lerobot_pc_success": float(info["aggregated"]["pc_success"]),
        "mean_hold_steps": float(np.mean(hook.holds)) if hook.holds else 0.0,
        "episodes": episodes,
    }
