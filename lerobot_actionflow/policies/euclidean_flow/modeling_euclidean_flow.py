"""``euclidean_flow``: Diffusion Policy with a rectified linear flow instead of diffusion.

Training (App. B, Eq. 5-6), on min-max normalised chunks ``a_1 (B, H, A)``::

    a_0 ~ N(0, I),  t ~ U[0, 1],  a_t = t a_1 + (1 - t) a_0,  u = a_1 - a_0,
    loss = mean ||v_theta(a_t, t, o) - u||^2

Sampling (Eq. 7): ``K`` Euler steps ``a_{k+1} = a_k + v_theta(a_k, t_k, o) (t_{k+1} - t_k)`` on a
uniform or exponentially spaced grid (App. E), ``K`` network calls per chunk. ``K`` and the
spacing are read from the config at every call (or passed per call), so they change without
retraining.

Observations ``o``: per step, ``[state, image features, environment state, point-cloud feature]``
concatenated into ``cond (B, S, D)`` (``S = n_obs_steps``); images go through LeRobot's
``DiffusionRgbEncoder``, the point cloud (world frame) through a PointNet.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from functools import partial

import torch
from lerobot.policies.diffusion.modeling_diffusion import DiffusionRgbEncoder
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.policies.utils import populate_queues
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE
from torch import Tensor, nn

from lerobot_actionflow.flow.euclidean import linear_path, sample
from lerobot_actionflow.flow.guidance import inpaint_sample_euclidean
from lerobot_actionflow.flow.schedules import evaluation_times, make_time_grid, sample_train_times
from lerobot_actionflow.nn.pointnet import PointNetEncoder
from lerobot_actionflow.policies.euclidean_flow.backbones import make_backbone
from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig
from lerobot_actionflow.policies.euclidean_flow.sampler_program import EuclideanFlowSamplerProgram
from lerobot_actionflow.policies.execution import (
    PreviousChunk,
    TargetSmoother,
    history_with_step,
    plan_chunk,
    rtc_config_of,
    rtc_guidance,
)
from lerobot_actionflow.policies.exported import ExportedSamplerLoading, ExportedSamplers
from lerobot_actionflow.policies.flow_options import check_rtc_solver
from lerobot_actionflow.policies.inputs import check_num_inference_steps, check_observation
from lerobot_actionflow.policies.loading import StrictLoading


class ObservationEncoder(nn.Module):
    """Observation steps -> conditioning features ``(B, S, D)``.

    Input batch: ``observation.state (B, S, d_s)``, ``observation.images (B, S, N, 3, H, W)``
    (cameras stacked), ``observation.environment_state (B, S, d_e)``, the point cloud
    ``(B, S, M, 3)``, each only if configured. ``D = d_s + N * F + d_e + d_p`` with ``F`` the RGB
    encoder's feature size and ``d_p`` the PointNet's.
    """

    def __init__(self, config: EuclideanFlowConfig):
        super().__init__()
        self.use_state = config.robot_state_feature is not None
        self.use_env = config.read_env_state_feature is not None
        self.num_cameras = len(config.image_features)
        self.separate = config.use_separate_rgb_encoder_per_camera
        dim = config.robot_state_feature.shape[0] if self.use_state else 0
        dim += config.env_state_feature.shape[0] if self.use_env else 0
        if self.num_cameras:
            if self.separate:
                self.rgb_encoder = nn.ModuleList(DiffusionRgbEncoder(config) for _ in range(self.num_cameras))
                feat = self.rgb_encoder[0].feature_dim
            else:
                self.rgb_encoder = DiffusionRgbEncoder(config)
                feat = self.rgb_encoder.feature_dim
            dim += feat * self.num_cameras
        self.point_cloud_key = config.point_cloud_key
        if self.point_cloud_key is not None:
            self.point_encoder = PointNetEncoder(
                config.point_cloud_width, config.point_cloud_feature_dim, config.point_cloud_scale
            )
            dim += config.point_cloud_feature_dim
        self.feature_dim = dim

    def forward(self, batch: dict[str, Tensor]) -> Tensor:
        feats = []
        if self.use_state:
            feats.append(batch[OBS_STATE])
        if self.num_cameras:
            images = batch[OBS_IMAGES]  # (B, S, N, C, H, W)
            b, s = images.shape[:2]
            if self.separate:
                per_cam = [enc(images[:, :, i].flatten(0, 1)) for i, enc in enumerate(self.rgb_encoder)]
                feats.append(torch.cat(per_cam, dim=-1).reshape(b, s, -1))
            else:
                feats.append(self.rgb_encoder(images.flatten(0, 2)).reshape(b, s, -1))
        if self.use_env:
            feats.append(batch[OBS_ENV_STATE])
        if self.point_cloud_key is not None:
            feats.append(self.point_encoder(batch[self.point_cloud_key]))
        return torch.cat(feats, dim=-1)


class EuclideanFlowPolicy(ExportedSamplerLoading, StrictLoading, PreTrainedPolicy):
    """Rectified-flow action-chunking policy (see module docstring)."""

    config_class = EuclideanFlowConfig
    name = "euclidean_flow"
    #: What ``actionflow-export`` exports (:mod:`lerobot_actionflow.policies.exported`).
    sampler_program = EuclideanFlowSamplerProgram

    def __init__(self, config: EuclideanFlowConfig, **kwargs):
        # kwargs: LeRobot's factory passes dataset_stats / dataset_meta; normalisation lives in
        # the processor pipeline, so they are not needed here.
        super().__init__(config)
        config.validate_features()
        self.config = config
        self.obs_encoder = ObservationEncoder(config)
        self.velocity_net = make_backbone(config, self.obs_encoder.feature_dim)
        self._queues: dict[str, deque] = {}
        #: Exported samplers attached by ``from_pretrained`` (or ``attach_exported_samplers``).
        self.exported_samplers: ExportedSamplers | None = None
        self.reset()

    def get_optim_params(self):
        return self.parameters()

    def reset(self):
        """Clear the observation and action queues (call on ``env.reset()``)."""
        n = self.config.n_obs_steps
        self._queues = {ACTION: deque(maxlen=self.config.n_action_steps)}
        self._smoother = TargetSmoother(self.config.target_smoothing)
        self._previous_chunk = PreviousChunk()
        if self.config.robot_state_feature is not None:
            self._queues[OBS_STATE] = deque(maxlen=n)
        if self.config.read_env_state_feature is not None:
            self._queues[OBS_ENV_STATE] = deque(maxlen=n)
        if self.config.image_features:
            self._queues[OBS_IMAGES] = deque(maxlen=n)
        if self.config.point_cloud_key is not None:
            self._queues[self.config.point_cloud_key] = deque(maxlen=n)

    # ----------------------------------------------------------------------------- input checks
    def _prepare(self, batch: dict[str, Tensor], with_time: bool) -> dict[str, Tensor]:
        """Check every used observation feature and stack the cameras.

        ``with_time``: tensors are ``(B, S, *shape)`` (training and offline chunks), else
        ``(B, *shape)`` (one environment step). Every check of the policy's inputs happens here
        (through :func:`lerobot_actionflow.policies.inputs.check_observation`: floating inputs are
        cast to the policy's dtype, anything else is refused with a ``ValueError`` naming the
        feature, the expected shape and dtype, and what was given). Only the features the policy
        reads are returned.
        """
        shapes = {key: tuple(ft.shape) for key, ft in self.config.used_input_features.items()}
        dtype = next(self.velocity_net.parameters()).dtype
        out = check_observation(batch, shapes, self.config.n_obs_steps, with_time, dtype)
        if self.config.image_features:
            dim = 2 if with_time else 1
            out[OBS_IMAGES] = torch.stack([out[k] for k in self.config.image_features], dim=dim)
        return out

    def _check_action(self, batch: dict[str, Tensor]) -> Tensor:
        expected = (self.config.horizon, self.config.action_feature.shape[0])
        if ACTION not in batch:
            raise ValueError(
                f"missing '{ACTION}' for training: expected shape (B, {expected[0]}, {expected[1]})"
            )
        a = batch[ACTION]
        if a.ndim != 3 or tuple(a.shape[1:]) != expected:
            raise ValueError(
                f"'{ACTION}' has shape {tuple(a.shape)}, expected (B, {expected[0]}, {expected[1]})"
            )
        if not torch.isfinite(a).all():
            raise ValueError(f"'{ACTION}' contains non-finite values (nan or inf)")
        return a

    # ---------------------------------------------------------------------------------- training
    def forward(self, batch: dict[str, Tensor], reduction: str = "mean") -> tuple[Tensor, dict | None]:
        """Flow-matching loss. Batch: observations ``(B, S, ...)``, ``action (B, H, A)``,
        optional ``action_is_pad (B, H)``. ``reduction="none"`` gives the per-sample loss ``(B,)``."""
        a1 = self._check_action(batch)
        obs = self._prepare(batch, with_time=True)
        cond = self.obs_encoder(obs)
        a0 = torch.randn_like(a1)
        t = sample_train_times(
            a1.shape[0],
            self.config.train_time_distribution,
            beta=self.config.train_time_beta,
            logit_normal=self.config.train_time_logit_normal,
            dtype=a1.dtype,
            device=a1.device,
        )
        a_t, u = linear_path(a0, a1, t)
        err = (self.velocity_net(a_t, t, cond) - u).pow(2)  # (B, H, A)
        if self.config.do_mask_loss_for_padding and "action_is_pad" in batch:
            valid = (~batch["action_is_pad"]).unsqueeze(-1).to(err.dtype)  # (B, H, 1)
            per_sample = (err * valid).sum((1, 2)) / (valid.sum((1, 2)) * err.shape[-1]).clamp_min(1)
        else:
            per_sample = err.mean((1, 2))
        if reduction == "none":
            return per_sample, None
        if reduction != "mean":
            raise ValueError(f"reduction must be 'mean' or 'none', got {reduction!r}")
        return per_sample.mean(), None

    # --------------------------------------------------------------------------------- inference
    @torch.no_grad()
    def sample_chunk(
        self,
        obs: dict[str, Tensor],
        noise: Tensor | None = None,
        num_inference_steps: int | None = None,
        time_spacing: str | None = None,
    ) -> Tensor:
        """Full normalised chunk ``(B, H, A)`` from prepared observations ``(B, S, ...)``:
        ``K`` Euler or midpoint steps (``solver``) from ``a_0 = noise`` (``N(0, I)`` if not given)
        on the time grid."""
        times = self._times(num_inference_steps, time_spacing, obs)
        return self.sample_from_observations(obs, self._initial_noise(noise, obs), times)

    def sample_from_observations(self, obs: dict[str, Tensor], noise: Tensor, times: Tensor) -> Tensor:
        """The sampler from prepared observations to the full normalised chunk, on tensors only
        (what :mod:`lerobot_actionflow.policies.exported` exports, through
        :class:`EuclideanFlowSamplerProgram`).

        Args:
            obs: the prepared history (:meth:`_prepare`): ``observation.state (B, S, d_s)``,
                ``observation.images (B, S, N, C, H, W)``, ``observation.environment_state
                (B, S, d_e)``, the point cloud, each only if the policy reads it.
            noise: ``a_0 (B, H, A)``; times: the ``K + 1`` flow times.
        Returns:
            ``(B, H, A)``, clipped to ``[-1, 1]`` with ``clip_sample``.
        """
        cond = self.obs_encoder(obs)  # (B, S, D)
        chunk = sample(self._velocity(cond, times, self.config.solver), noise, times, self.config.solver)
        return chunk.clamp(-1.0, 1.0) if self.config.clip_sample else chunk

    def guided_sample_from_observations(
        self,
        obs: dict[str, Tensor],
        noise: Tensor,
        times: Tensor,
        target: Tensor,
        weights: Tensor,
        frozen: Tensor,
    ) -> Tensor:
        """:meth:`sample_from_observations` guided toward known actions (real-time chunking,
        :func:`lerobot_actionflow.flow.guidance.inpaint_sample_euclidean`, Euler steps).

        Args:
            obs, noise, times: as :meth:`sample_from_observations`.
            target: the known actions ``(B, H, A)`` aligned with the chunk; weights: ``(B, H)``
                in ``[0, 1]``; frozen: ``(B, H)`` bool, the actions returned exactly as
                ``target``'s.
        """
        cond = self.obs_encoder(obs)
        chunk = inpaint_sample_euclidean(
            self._velocity(cond, times, "euler"), noise, times, target, weights, frozen
        )
        if self.config.clip_sample:
            chunk = chunk.clamp(-1.0, 1.0)
        # The frozen prefix is the leftover itself, even where it lies outside the clip range.
        return torch.where(frozen[..., None], target, chunk)

    def supports_rtc(self) -> bool:
        """LeRobot's real-time chunking (``lerobot-rollout --inference.type=rtc``) is supported."""
        return True

    @torch.no_grad()
    def predict_action_chunk(
        self,
        batch: dict[str, Tensor],
        noise: Tensor | None = None,
        num_inference_steps: int | None = None,
        time_spacing: str | None = None,
        inference_delay: int | None = None,
        prev_chunk_left_over: Tensor | None = None,
        execution_horizon: int | None = None,
        **kwargs,
    ) -> Tensor:
        """The sampled actions from the current step on: ``(B, horizon - n_obs_steps + 1, A)``.

        ``batch`` holds the observation history ``(B, n_obs_steps, ...)``, oldest first (or
        ``(B, ...)`` when ``n_obs_steps == 1``). One step ``(B, ...)`` when ``n_obs_steps > 1``
        (what LeRobot's RTC engine sends) is appended to the policy's own history, as
        :meth:`select_action` does (an observation equal to the newest one is not appended
        twice). The chunk the network samples starts at the oldest observation step (see
        :class:`EuclideanFlowConfig`); the actions of the past steps are dropped here.

        Real-time chunking (LeRobot's RTC engine): ``prev_chunk_left_over`` ``(T, A)`` or
        ``(B, T, A)``, normalised like this method's output, holds the previous chunk's actions not
        executed yet, action ``i`` due at the step of the returned chunk's action ``i``. Its first
        ``inference_delay`` actions are reproduced exactly, and the chunk is guided toward the rest
        up to ``execution_horizon`` (:func:`lerobot_actionflow.flow.guidance.inpaint_sample_euclidean`;
        weights from the config's ``rtc_config``, which ``lerobot-rollout`` sets, else LeRobot's
        defaults). Without a leftover chunk the chunk is sampled as without RTC. Other keywords
        LeRobot's engines may pass are ignored.
        """
        obs = self._observation_history(batch)
        rtc = {"inference_delay": inference_delay, "execution_horizon": execution_horizon}
        return self._chunk(
            obs, noise, num_inference_steps, time_spacing, prev_chunk_left_over=prev_chunk_left_over, **rtc
        )

    def _chunk(
        self,
        obs: dict[str, Tensor],
        noise: Tensor | None,
        num_inference_steps: int | None,
        time_spacing: str | None = None,
        inference_delay: int | None = None,
        prev_chunk_left_over: Tensor | None = None,
        execution_horizon: int | None = None,
    ) -> Tensor:
        """:meth:`predict_action_chunk` on a prepared history ``(B, n_obs_steps, ...)``.

        The sampler used: an exported artefact for this program, K, batch size and device
        (:mod:`~lerobot_actionflow.policies.exported`; on the config's time grid), else eager.
        """
        rtc = rtc_config_of(self.config)
        guided = prev_chunk_left_over is not None and rtc is not None
        known: tuple[Tensor, ...] = ()  # the guided sampler's target, weights, frozen
        noise = self._initial_noise(noise, obs)
        if guided:
            check_rtc_solver(self.config.solver)
            guide = rtc_guidance(
                prev_chunk_left_over.to(noise),
                inference_delay,
                self.config.horizon,
                rtc,
                batch_size=noise.shape[0],
                execution_horizon=execution_horizon,
                offset=self.config.n_obs_steps - 1,
            )
            action_dim = self.config.action_feature.shape[0]
            if guide.target.shape[-1] != action_dim:
                raise ValueError(
                    f"prev_chunk_left_over must hold actions (..., {action_dim}), got last dimension "
                    f"{guide.target.shape[-1]}"
                )
            known = (guide.target.to(noise), guide.weights.to(noise), guide.frozen.to(noise.device))
        k = self.config.num_inference_steps if num_inference_steps is None else num_inference_steps
        on_config_grid = time_spacing in (None, self.config.time_spacing)
        # Exported artefacts take no point cloud (actionflow-export refuses such policies).
        if self.exported_samplers is not None and on_config_grid and self.config.point_cloud_key is None:
            exported = self.exported_samplers.get(
                noise.device, check_num_inference_steps(k), noise.shape[0], guided
            )
            if exported is not None:
                return self._from_current_step(exported(EuclideanFlowSamplerProgram.pack(obs, noise, known)))
        times = self._times(k, time_spacing, obs)
        if guided:
            return self._from_current_step(self.guided_sample_from_observations(obs, noise, times, *known))
        return self._from_current_step(self.sample_from_observations(obs, noise, times))

    def _observation_history(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """The prepared history ``(B, n_obs_steps, ...)`` of a history batch, or of one step
        appended to the policy's queues."""
        key, ft = next(iter(self.config.used_input_features.items()))
        x = batch.get(key)
        if self.config.n_obs_steps == 1 or not isinstance(x, Tensor) or x.ndim != len(ft.shape) + 1:
            return self._prepare(batch, with_time=True)
        return history_with_step(self._queues, self._prepare(batch, with_time=False), ACTION)

    def _initial_noise(self, noise: Tensor | None, obs: dict[str, Tensor]) -> Tensor:
        """``a_0 (B, H, A)``: ``noise`` checked, or drawn from ``N(0, I)``, in the policy's dtype."""
        first = next(iter(obs.values()))
        dtype = next(self.velocity_net.parameters()).dtype
        shape = (first.shape[0], self.config.horizon, self.config.action_feature.shape[0])
        if noise is None:
            return torch.randn(shape, dtype=dtype, device=first.device)
        if tuple(noise.shape) != shape:
            raise ValueError(f"noise has shape {tuple(noise.shape)}, expected {shape}")
        return noise.to(dtype)

    def _times(
        self, num_inference_steps: int | None, time_spacing: str | None, obs: dict[str, Tensor]
    ) -> Tensor:
        """The ``K + 1`` flow times (the config's K and grid unless given)."""
        k = self.config.num_inference_steps if num_inference_steps is None else num_inference_steps
        first = next(iter(obs.values()))
        return make_time_grid(
            check_num_inference_steps(k),
            time_spacing or self.config.time_spacing,
            rate=self.config.time_spacing_rate,
            dtype=next(self.velocity_net.parameters()).dtype,
            device=first.device,
        )

    def _velocity(self, cond: Tensor, times: Tensor, solver: str) -> Callable[[Tensor, int], Tensor]:
        """The velocity field conditioned on ``cond``, indexed by ``solver``'s evaluations over
        ``times`` (:func:`~lerobot_actionflow.flow.schedules.evaluation_times`)."""
        at = evaluation_times(times, solver)

        def velocity(a: Tensor, j: int) -> Tensor:
            return self.velocity_net(a, at[j].expand(a.shape[0]), cond)

        return velocity

    def _from_current_step(self, chunk: Tensor) -> Tensor:
        return chunk[:, self.config.n_obs_steps - 1 :]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], noise: Tensor | None = None) -> Tensor:
        """One action ``(B, A)`` for observations ``(B, ...)`` of the current step; a new chunk is
        generated every ``n_action_steps`` calls from the last ``n_obs_steps`` observations.

        With the config's execution options (:mod:`lerobot_actionflow.policies.execution`), the
        actions whose time passed during the inference delay are skipped, the returned target
        is smoothed exponentially along SE(3) geodesics, and each chunk after the first is guided
        toward the previous one (``guide_to_previous_chunk``)."""
        batch = {k: v for k, v in batch.items() if k != ACTION}
        obs = self._prepare(batch, with_time=False)
        self._queues = populate_queues(self._queues, obs)
        if not self._queues[ACTION]:
            history = {k: torch.stack(list(q), dim=1) for k, q in self._queues.items() if k != ACTION}
            predict = partial(self._chunk, noise=noise, num_inference_steps=None)
            actions = plan_chunk(predict, history, self.config, self._previous_chunk)
            self._queues[ACTION].extend(actions.transpose(0, 1))
        return self._smoother(self._queues[ACTION].popleft())
