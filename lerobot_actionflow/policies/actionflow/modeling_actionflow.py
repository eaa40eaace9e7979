"""ActionFlow as a LeRobot policy: batches in, SE(3) flow matching through the core out.

Training (Alg. 1): for a batch of observations and action chunks, draw ``q0`` in the current
EEF frame, a time ``t``, the point on the geodesic path and its local target velocities, and
regress the network's velocities onto them (translation errors in units of
``1 / translation_scale`` metres, so that the three terms have similar size).

Sampling (Alg. 2): ``K`` Euler (or midpoint, ``solver``) steps on SE(3) from ``q0``; the chunk is
returned as absolute EEF targets ``[x, y, z, rot6d, gripper]``.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from functools import partial

import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.policies.utils import populate_queues
from torch import Tensor

from lerobot_actionflow.flow import guidance, schedules, shortcut
from lerobot_actionflow.flow import se3 as se3_flow
from lerobot_actionflow.geometry import check_finite, check_quaternion, quaternion_to_matrix
from lerobot_actionflow.nn import ActionFlowNetwork, IPASize, ObservationTokens, PoseAdaptation
from lerobot_actionflow.nn.image_encoder import ResNet18Encoder
from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig
from lerobot_actionflow.policies.actionflow.sampler_program import ActionflowSamplerProgram
from lerobot_actionflow.policies.execution import (
    PreviousChunk,
    RTCGuidance,
    TargetSmoother,
    history_with_step,
    plan_chunk,
    rtc_config_of,
    rtc_guidance,
)
from lerobot_actionflow.policies.exported import ExportedSamplerLoading, ExportedSamplers
from lerobot_actionflow.policies.flow_options import check_rtc_solver, check_shortcut_sampling
from lerobot_actionflow.policies.inputs import check_num_inference_steps, check_observation
from lerobot_actionflow.policies.loading import StrictLoading
from lerobot_actionflow.schema import ACTION_DIM, ACTION_KEY, POSES_KEY, STATE_KEY
from lerobot_actionflow.schema.tensors import action_to_pose, pose_to_action

logger = logging.getLogger(__name__)


class ActionflowPolicy(ExportedSamplerLoading, StrictLoading, PreTrainedPolicy):
    config_class = ActionflowConfig
    name = "actionflow"
    #: What ``actionflow-export`` exports (:mod:`lerobot_actionflow.policies.exported`).
    sampler_program = ActionflowSamplerProgram

    def __init__(self, config: ActionflowConfig, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config = config
        #: Rows of observation.poses the network reads (config.pose_entities, else all).
        self.pose_rows = list(config.pose_entities) or list(range(config.poses_feature.shape[0]))
        self.num_entities = len(self.pose_rows)
        self.image_keys = list(config.image_features)
        camera_entities = tuple(config.camera_entities) or (0,) * len(self.image_keys)
        self.image_encoder = (
            ResNet18Encoder(config.image_size, config.image_encoder_weights) if self.image_keys else None
        )
        size = IPASize(
            dim=config.dim,
            num_heads=config.num_heads,
            head_dim=config.head_dim,
            num_query_points=config.num_query_points,
            num_value_points=config.num_value_points,
        )
        self.network = ActionFlowNetwork(
            num_entities=self.num_entities,
            n_obs_steps=config.n_obs_steps,
            horizon=config.horizon,
            num_scalars=config.num_scalars,
            camera_entities=camera_entities,
            image_feature_dim=ResNet18Encoder.out_dim,
            size=size,
            depth=config.num_layers,
            mlp_ratio=config.mlp_ratio,
            dropout=config.dropout,
            adaptation=PoseAdaptation(
                config.adaptation_frame, config.translation_scale, config.squash_translations
            ),
            translation_frame=config.translation_velocity_frame,
            point_groups=config.point_cloud_groups if config.point_cloud_key else 0,
            point_group_size=config.point_cloud_group_size,
            point_width=config.point_cloud_width,
            step_size_conditioning=config.few_step_objective == "shortcut",
        )
        #: Per-step shape of every observation feature the policy reads.
        self._observation_shapes = {POSES_KEY: tuple(config.poses_feature.shape)}
        if config.num_scalars:
            self._observation_shapes[STATE_KEY] = tuple(config.robot_state_feature.shape)
        for key in self.image_keys:  # any H, W: the image encoder resizes to config.image_size
            self._observation_shapes[key] = (config.image_features[key].shape[0], "H", "W")
        #: The point-cloud feature read (its latest step becomes the point tokens), or None.
        self.point_cloud_key = config.point_cloud_key
        if self.point_cloud_key is not None:
            self._observation_shapes[self.point_cloud_key] = tuple(config.point_cloud_feature.shape)
        #: ``torch.compile`` graphs, by program (True: the guided one), made at their first chunk.
        self._compiled_samplers: dict[bool, Callable] = {}
        #: Exported samplers attached by ``from_pretrained`` (or ``attach_exported_samplers``).
        self.exported_samplers: ExportedSamplers | None = None
        self.reset()

    # -- LeRobot API ------------------------------------------------------------------------------
    def get_optim_params(self):
        return self.parameters()

    def reset(self):
        """Clear the observation history and the action queue (call on env reset)."""
        keys = [POSES_KEY, *self.image_keys]
        if self.config.num_scalars:
            keys.append(STATE_KEY)
        if self.point_cloud_key is not None:
            keys.append(self.point_cloud_key)
        self._queues = {k: deque(maxlen=self.config.n_obs_steps) for k in keys}
        self._queues[ACTION_KEY] = deque(maxlen=self.config.n_action_steps)
        self._smoother = TargetSmoother(self.config.target_smoothing)
        self._previous_chunk = PreviousChunk()

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict[str, float]]:
        """Flow-matching loss on a batch with ``observation.*`` ``(B, n_obs_steps, ...)`` and
        ``action`` ``(B, horizon, 10)``; returns the loss and its translation / rotation /
        gripper terms."""
        cfg = self.config
        obs = self._observation_tokens(self.check_observation(batch, with_time=True))
        action = _require(batch, ACTION_KEY)
        b = action.shape[0]
        if action.shape[1:] != (cfg.horizon, ACTION_DIM):
            raise ValueError(
                f"'{ACTION_KEY}' must have shape (B, {cfg.horizon}, {ACTION_DIM}), got {tuple(action.shape)}"
            )
        check_finite(action, ACTION_KEY)
        x1 = se3_flow.PoseChunk(*action_to_pose(action))

        encoded = self.network.encode_observations(obs)
        noise = se3_flow.draw_local_noise(
            b, cfg.horizon, cfg.noise_sigma, cfg.noise_rotation, cfg.noise_kappa, dtype=action.dtype,
            device=action.device,
        )  # fmt: skip
        x0 = se3_flow.noise_to_world(noise, encoded.r_ref, encoded.p_ref)
        t = schedules.sample_train_times(
            b, cfg.train_time_distribution, cfg.train_time_beta, dtype=action.dtype, device=action.device,
            logit_normal=cfg.train_time_logit_normal,
        )  # fmt: skip
        d = None
        n_short = round(cfg.shortcut_fraction * b) if cfg.few_step_objective == "shortcut" else 0
        if n_short:
            # The first n_short samples get shortcut times and step sizes (flow.shortcut).
            t_s, d_s = shortcut.draw_shortcut_times(n_short, cfg.shortcut_max_steps, None, t.dtype, t.device)
            t = torch.cat((t_s, t[n_short:]))
        x_t, u_t = se3_flow.geodesic_path(x0, x1, t)
        if cfg.few_step_objective == "shortcut":
            d = torch.zeros_like(t)
        if n_short:
            u_t = self._with_shortcut_targets(encoded, x_t, u_t, t_s, d_s)
            d = torch.cat((2 * d_s, d[n_short:]))
        pred = self.network.velocity(encoded, x_t, t, d=d)

        err_p = ((pred.p - u_t.p) * cfg.translation_scale).square().sum(-1)  # (B, H)
        err_r = (pred.r - u_t.r).square().sum(-1)
        err_g = (pred.g - u_t.g).square()
        valid = (
            ~batch["action_is_pad"] if "action_is_pad" in batch else torch.ones_like(err_g, dtype=torch.bool)
        )
        w = valid.to(err_p.dtype)
        denom = w.sum().clamp_min(1.0)
        terms = {
            name: (e * w).sum() / denom
            for name, e in (("translation", err_p), ("rotation", err_r), ("gripper", err_g))
        }
        loss = (
            cfg.loss_weight_translation * terms["translation"]
            + cfg.loss_weight_rotation * terms["rotation"]
            + cfg.loss_weight_gripper * terms["gripper"]
        )
        return loss, {f"loss_{k}": v.item() for k, v in terms.items()}

    @torch.no_grad()
    def _with_shortcut_targets(
        self,
        encoded,
        x_t: se3_flow.PoseChunk,
        u_t: se3_flow.PoseVelocity,
        t_s: Tensor,
        d_s: Tensor,
    ) -> se3_flow.PoseVelocity:
        """``u_t`` with its first ``len(t_s)`` rows replaced by the shortcut targets of
        :func:`lerobot_actionflow.flow.shortcut.shortcut_target` (the model's own two steps of
        size ``d_s``, no gradient)."""
        n = t_s.shape[0]
        enc = encoded.first(n)
        x_s = se3_flow.PoseChunk(x_t.r[:n], x_t.p[:n], x_t.g[:n])

        def field(x, t, d):
            return self.network.velocity(enc, x, t, d=d)

        inner = shortcut.inner_conditioning(d_s, self.config.shortcut_max_steps)
        target = shortcut.shortcut_target(field, x_s, t_s, d_s, cond_d=inner)
        return se3_flow.PoseVelocity(*(torch.cat((a, b[n:])) for a, b in zip(target, u_t, strict=True)))

    def supports_rtc(self) -> bool:
        """LeRobot's real-time chunking (``lerobot-rollout --inference.type=rtc``) is supported."""
        return True

    @torch.no_grad()
    def predict_action_chunk(
        self,
        batch: dict[str, Tensor],
        noise: se3_flow.LocalNoise | None = None,
        num_inference_steps: int | None = None,
        inference_delay: int | None = None,
        prev_chunk_left_over: Tensor | None = None,
        execution_horizon: int | None = None,
        **kwargs,
    ) -> Tensor:
        """The sampled actions from the current step on: ``(B, horizon, 10)`` (the chunk starts at
        the current step; see :class:`ActionflowConfig`).

        Args:
            batch: the observation history ``(B, n_obs_steps, ...)``, oldest first (or
                ``(B, ...)`` when ``n_obs_steps == 1``). One step ``(B, ...)`` when
                ``n_obs_steps > 1`` (what LeRobot's RTC engine sends) is appended to the policy's
                own history, as :meth:`select_action` does (an observation equal to the newest
                one is not appended twice).
            noise: initial noise in the EEF frame (drawn if None).
            num_inference_steps: integration steps K >= 1 (default: the config's; ``2K`` network
                calls with ``solver="midpoint"``); no retraining needed.
            inference_delay, prev_chunk_left_over, execution_horizon: real-time chunking (LeRobot's
                RTC engine). ``prev_chunk_left_over`` ``(T, 10)`` or ``(B, T, 10)``: the previous
                chunk's actions not executed yet, action ``i`` due at the step of this chunk's
                action ``i``. Its first ``inference_delay`` actions are reproduced exactly, and the
                chunk is guided toward the rest up to ``execution_horizon``, along SE(3) geodesics
                (:mod:`lerobot_actionflow.flow.guidance`; weights from the config's ``rtc_config``,
                which ``lerobot-rollout`` sets, else LeRobot's defaults). Without a leftover chunk
                (or with ``rtc_config.enabled`` False) the chunk is sampled as without RTC.
            **kwargs: other keywords LeRobot's inference engines may pass; unused.

        Raises:
            ValueError: a bad observation (:meth:`check_observation`), K < 1, a bad leftover, or
                a leftover with ``solver="midpoint"`` (the guidance integrates with Euler).
        """
        obs = self._observation_history(batch)
        rtc = {"inference_delay": inference_delay, "execution_horizon": execution_horizon}
        return self._chunk(obs, noise, num_inference_steps, prev_chunk_left_over=prev_chunk_left_over, **rtc)

    def _chunk(
        self,
        obs: dict[str, Tensor],
        noise: se3_flow.LocalNoise | None,
        num_inference_steps: int | None,
        inference_delay: int | None = None,
        prev_chunk_left_over: Tensor | None = None,
        execution_horizon: int | None = None,
    ) -> Tensor:
        """:meth:`predict_action_chunk` on a checked history ``(B, n_obs_steps, ...)``."""
        rtc = rtc_config_of(self.config)
        if prev_chunk_left_over is None or rtc is None:
            return self._predict(obs, noise, num_inference_steps)
        check_rtc_solver(self.config.solver)
        guide = rtc_guidance(
            prev_chunk_left_over.to(self._dtype),
            inference_delay,
            self.config.horizon,
            rtc,
            batch_size=obs[POSES_KEY].shape[0],
            execution_horizon=execution_horizon,
        )
        return self._predict(obs, noise, num_inference_steps, guide)

    def _observation_history(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """The checked history ``(B, n_obs_steps, ...)`` of a history batch, or of one step
        appended to the policy's queues."""
        poses = batch.get(POSES_KEY)
        per_step = len(self._observation_shapes[POSES_KEY])
        one_step = self.config.n_obs_steps > 1 and isinstance(poses, Tensor) and poses.ndim == per_step + 1
        if not one_step:
            return self.check_observation(batch, with_time=True)
        return history_with_step(self._queues, self.check_observation(batch, with_time=False), ACTION_KEY)

    def _predict(
        self,
        obs: dict[str, Tensor],
        noise: se3_flow.LocalNoise | None,
        num_inference_steps: int | None,
        guide: RTCGuidance | None = None,
    ) -> Tensor:
        """:meth:`predict_action_chunk` on an observation history already checked; with ``guide``,
        guided by real-time chunking (:meth:`guided_sample_from_observations`).

        The sampler used, first that applies: an exported artefact for this program, K, batch
        size and device (:mod:`~lerobot_actionflow.policies.exported`), the
        ``torch.compile`` graph (``compile_sampler``), eager.
        """
        cfg = self.config
        k = check_num_inference_steps(
            cfg.num_inference_steps if num_inference_steps is None else num_inference_steps
        )
        poses = obs[POSES_KEY]
        b, device, dtype = poses.shape[0], poses.device, poses.dtype
        guided = guide is not None
        known: tuple[Tensor, ...] = ()  # the guided sampler's target, weights, frozen
        if guided:
            target = guide.target.to(device=device, dtype=dtype)
            if target.shape[-1] != ACTION_DIM:
                raise ValueError(
                    f"prev_chunk_left_over must hold actions (..., {ACTION_DIM}) [x y z rot6d gripper], "
                    f"got last dimension {target.shape[-1]}"
                )
            known = (target, guide.weights.to(device=device, dtype=dtype), guide.frozen.to(device))
        if noise is None:
            noise = se3_flow.draw_local_noise(
                b, cfg.horizon, cfg.noise_sigma, cfg.noise_rotation, cfg.noise_kappa, dtype=dtype,
                device=device,
            )  # fmt: skip
        state = obs[STATE_KEY] if cfg.num_scalars else None
        image_features = self._image_features(obs)
        points = self._latest_points(obs)
        # Exported artefacts take no point cloud (actionflow-export refuses such policies).
        use_exported = self.exported_samplers is not None and points is None
        exported = self.exported_samplers.get(device, k, b, guided) if use_exported else None
        if exported is not None:
            return exported(ActionflowSamplerProgram.pack(poses, state, image_features, noise, known or None))
        times = schedules.make_time_grid(k, cfg.time_spacing, cfg.time_spacing_rate, dtype, device)
        args = (poses, state, image_features, noise.r, noise.p, noise.g, times, *known, points)
        sampler = self.guided_sample_from_observations if guided else self.sample_from_observations
        if self._use_compiled_sampler(device):
            if guided not in self._compiled_samplers:
                self._compiled_samplers[guided] = self._compile(sampler, device)
            traceable = {"frozen_path": True} if guided else {}
            # CUDA-graph replays reuse their output buffers: copy before anyone keeps a view.
            return self._compiled_samplers[guided](*args, **traceable).clone()
        return sampler(*args)

    def _compile(self, sampler, device: torch.device):
        """``torch.compile`` of a sampler (:meth:`sample_from_observations` or
        :meth:`guided_sample_from_observations`), one graph per K.

        On CUDA with ``compile_mode`` ("reduce-overhead": CUDA graphs). On the CPU, where a
        batch-1 chunk is bound by operator overhead and by streaming the weights, with inductor's
        ``freezing`` (weights folded in as constants and pre-packed for oneDNN's matmuls) and its
        C++ wrapper (kernels called from C++, not Python). Frozen weights are a snapshot: the
        compiled sampler is dropped whenever the weights may change (:meth:`train`,
        :meth:`load_state_dict`); code that edits parameters in place must call
        :meth:`reset_compiled_sampler`.
        """
        if device.type == "cpu":
            return torch.compile(sampler, dynamic=False, options={"freezing": True, "cpp_wrapper": True})
        return torch.compile(sampler, mode=self.config.compile_mode, dynamic=False)

    def reset_compiled_sampler(self) -> None:
        """Forget the compiled samplers; the next chunk compiles them again with the current weights."""
        self._compiled_samplers.clear()

    def train(self, mode: bool = True):
        if mode:
            self.reset_compiled_sampler()
        return super().train(mode)

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        self.reset_compiled_sampler()
        return super().load_state_dict(state_dict, strict=strict, assign=assign)

    def _use_compiled_sampler(self, device: torch.device) -> bool:
        flag = self.config.compile_sampler
        return device.type == "cuda" if flag is None else bool(flag)

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], noise: se3_flow.LocalNoise | None = None) -> Tensor:
        """One action ``(B, 10)``: keeps ``n_obs_steps`` of history (the first observation
        repeated at the start) and re-plans a chunk once ``n_action_steps`` have been used.

        With the config's execution options (:mod:`lerobot_actionflow.policies.execution`), the
        actions whose time passed during the inference delay are skipped, the returned target
        is smoothed exponentially along SE(3) geodesics, and each chunk after the first is guided
        toward the previous one (``guide_to_previous_chunk``)."""
        # Checked before it enters the history, so that a refused observation leaves no trace.
        step = self.check_observation(batch, with_time=False)
        self._queues = populate_queues(self._queues, step)
        if not self._queues[ACTION_KEY]:
            history = {k: torch.stack(list(q), dim=1) for k, q in self._queues.items() if k != ACTION_KEY}
            predict = partial(self._chunk, noise=noise, num_inference_steps=None)
            actions = plan_chunk(predict, history, self.config, self._previous_chunk)
            self._queues[ACTION_KEY].extend(actions.transpose(0, 1))
        return self._smoother(self._queues[ACTION_KEY].popleft())

    # -- internals ---------------------------------------------------------------------------------
    def sample_from_observations(
        self,
        poses: Tensor,
        state: Tensor | None,
        image_features: Tensor | None,
        noise_r: Tensor,
        noise_p: Tensor,
        noise_g: Tensor,
        times: Tensor,
        points: Tensor | None = None,
    ) -> Tensor:
        """The sampler from checked observations to actions, as one tensor-in/tensor-out function
        (what ``torch.compile`` compiles and :mod:`~lerobot_actionflow.policies.exported`
        exports, through :class:`ActionflowSamplerProgram`).

        Args:
            poses: ``(B, n_obs_steps, N, 7)`` with unit quaternions; state: ``(B, n_obs_steps, 11)``
                or None when the policy reads no state scalars; image_features: encoder outputs
                ``(B, n_obs_steps, N_cam, 512)`` or None.
            noise_r, noise_p, noise_g: initial noise in the EEF frame ``(B, H, 3, 3)``,
                ``(B, H, 3)``, ``(B, H)``; times: the ``K + 1`` flow times.
            points: the latest step's point cloud ``(B, M, 3)`` when the policy reads one.
        Returns:
            actions ``(B, H, 10)``.
        """
        obs = self._tokens(poses, state, image_features, points)
        return self._sample(
            obs.r, obs.p, obs.scalars, obs.image_features, noise_r, noise_p, noise_g, times, points=obs.points
        )

    def _sample(
        self, obs_r, obs_p, scalars, image_features, noise_r, noise_p, noise_g, times, points=None
    ) -> Tensor:
        """The K-step sampler from network inputs (:class:`ObservationTokens`' tensors) to actions."""
        obs = ObservationTokens(obs_r, obs_p, scalars, image_features, points)
        noise = se3_flow.LocalNoise(noise_r, noise_p, noise_g)
        x0, velocity = self._flow_start(obs, noise, times, self.config.solver)
        x1 = se3_flow.sample(velocity, x0, times, self.config.solver)
        return pose_to_action(x1.r, x1.p, x1.g.clamp(-1.0, 1.0))

    def _flow_start(
        self, obs: ObservationTokens, noise: se3_flow.LocalNoise, times: Tensor, solver: str
    ) -> tuple[se3_flow.PoseChunk, se3_flow.VelocityField]:
        """The initial noise in the world frame and the network's field ``velocity(x, j)`` for the
        ``j``-th evaluation of ``solver`` over ``times``, the observations encoded once."""
        encoded = self.network.encode_observations(obs)
        x0 = se3_flow.noise_to_world(noise, encoded.r_ref, encoded.p_ref)
        # Every flow time of the chunk is known: condition all K (Euler) or 2K (midpoint)
        # evaluations with one call per block.
        at = schedules.evaluation_times(times, solver)
        shifts = self.network.time_shifts(at, self._step_sizes(times.shape[0] - 1, at.shape[0], times))

        def velocity(x: se3_flow.PoseChunk, j: int) -> se3_flow.PoseVelocity:
            return self.network.velocity(encoded, x, shifts=[s[j : j + 1] for s in shifts])

        return x0, velocity

    def guided_sample_from_observations(
        self,
        poses: Tensor,
        state: Tensor | None,
        image_features: Tensor | None,
        noise_r: Tensor,
        noise_p: Tensor,
        noise_g: Tensor,
        times: Tensor,
        target: Tensor,
        weights: Tensor,
        frozen: Tensor,
        points: Tensor | None = None,
        frozen_path: bool | None = None,
    ) -> Tensor:
        """:meth:`sample_from_observations` guided toward known actions (real-time chunking,
        :func:`lerobot_actionflow.flow.guidance.inpaint_sample`): what ``torch.compile`` compiles
        and :mod:`~lerobot_actionflow.policies.exported` exports for guided chunks.

        Args:
            poses, state, image_features, noise_r, noise_p, noise_g, times, points: as
                :meth:`sample_from_observations` (Euler steps only).
            target: the known actions ``(B, H, 10)`` aligned with the chunk (the previous chunk's
                leftover; rows of weight 0 are ignored and may be zeros).
            weights: ``(B, H)`` guidance weights in ``[0, 1]``; frozen: ``(B, H)`` bool, the
                actions returned exactly as ``target``'s (weight 1 there).
            frozen_path: blend the frozen actions along their path after every step; None: only
                when an action is frozen (a data-dependent branch, which a traced graph cannot
                hold, so the compiled and exported samplers pass True: the same actions).
        Returns:
            actions ``(B, H, 10)``.
        """
        obs = self._tokens(poses, state, image_features, points)
        noise = se3_flow.LocalNoise(noise_r, noise_p, noise_g)
        x0, velocity = self._flow_start(obs, noise, times, "euler")  # the guidance steers Euler steps
        # Padding rows (weight 0) are zeros, not poses: stand the noise in for them.
        goal = guidance.select(weights > 0, se3_flow.PoseChunk(*action_to_pose(target)), x0)
        x1 = guidance.inpaint_sample(velocity, x0, times, goal, weights, frozen, frozen_path=frozen_path)
        out = pose_to_action(x1.r, x1.p, x1.g.clamp(-1.0, 1.0))
        # The frozen prefix is the leftover itself, bit for bit (not its Gram-Schmidt round trip).
        return torch.where(frozen[..., None], target.to(out), out)

    def _step_sizes(self, num_steps: int, num_evaluations: int, times: Tensor) -> Tensor | None:
        """The step-size conditioning of each network evaluation of a K-step chunk: ``1/K`` (0 for
        ``K >= shortcut_max_steps``) with the shortcut objective, else None (plain flow)."""
        cfg = self.config
        if cfg.few_step_objective != "shortcut":
            return None
        check_shortcut_sampling(cfg)
        d = shortcut.sampling_step_size(num_steps, cfg.shortcut_max_steps)
        return torch.full((num_evaluations,), d, dtype=times.dtype, device=times.device)

    def check_observation(self, batch: dict[str, Tensor], with_time: bool = True) -> dict[str, Tensor]:
        """Every check of the observations the policy reads, in one place.

        ``with_time``: tensors are ``(B, n_obs_steps, ...)`` (``forward``,
        ``predict_action_chunk``), else ``(B, ...)`` (one step, ``select_action``). Shapes come
        from the config's input features; floating inputs are cast to the policy's dtype (see
        :mod:`lerobot_actionflow.policies.inputs`). The quaternions of ``observation.poses`` must
        be unit within ``rotation_tolerance`` and are returned normalised, keeping only the rows
        of ``pose_entities`` when the config names them.

        Raises:
            ValueError: naming the feature, the expected shape and dtype, and what was given.
        """
        obs = check_observation(
            batch, self._observation_shapes, self.config.n_obs_steps, with_time, self._dtype
        )
        poses = obs[POSES_KEY]
        quat = check_quaternion(poses[..., 3:], atol=self.config.rotation_tolerance, name=POSES_KEY)
        poses = torch.cat([poses[..., :3], quat], dim=-1)
        if self.config.pose_entities:
            poses = poses[..., self.pose_rows, :]
        obs[POSES_KEY] = poses
        return obs

    @property
    def _dtype(self) -> torch.dtype:
        return next(self.network.parameters()).dtype

    def _observation_tokens(self, obs: dict[str, Tensor]) -> ObservationTokens:
        """Network inputs from a checked observation history (:meth:`check_observation`)."""
        return self._tokens(
            obs[POSES_KEY], obs.get(STATE_KEY), self._image_features(obs), self._latest_points(obs)
        )

    def _latest_points(self, obs: dict[str, Tensor]) -> Tensor | None:
        """The latest step's checked point cloud ``(B, N, 3)``: its first N = ``point_cloud_prefix``
        rows, or all M when that is None; None when the policy reads no cloud."""
        if self.point_cloud_key is None:
            return None
        return obs[self.point_cloud_key][:, -1, : self.config.point_cloud_prefix]

    def _image_features(self, obs: dict[str, Tensor]) -> Tensor | None:
        """ResNet18 features ``(B, n_obs_steps, N_cam, F)`` of the checked images, or None."""
        if not self.image_keys:
            return None
        b, s = obs[POSES_KEY].shape[:2]
        feats = [self.image_encoder(obs[key].flatten(0, 1)).view(b, s, -1) for key in self.image_keys]
        return torch.stack(feats, 2)

    def _tokens(
        self, poses: Tensor, state: Tensor | None, image_features: Tensor | None, points: Tensor | None = None
    ) -> ObservationTokens:
        """Network inputs from checked poses ``(B, S, N, 7)`` (unit quaternions), the state
        ``(B, S, 11)`` (read only when ``num_scalars``), image features and the latest point
        cloud ``(B, M, 3)`` (or None)."""
        cfg = self.config
        r, p = quaternion_to_matrix(poses[..., 3:]), poses[..., :3]
        scalars = None
        if cfg.num_scalars:
            eef_scalars = state[..., list(cfg.state_scalar_indices)] * cfg.state_scalar_scale
            # Only the EEF token carries scalars; the object slots get zeros.
            others = eef_scalars.new_zeros(*eef_scalars.shape[:2], self.num_entities - 1, cfg.num_scalars)
            scalars = torch.cat((eef_scalars[:, :, None], others), 2)
        return ObservationTokens(r, p, scalars, image_features, points)


def _require(batch: dict[str, Tensor], key: str) -> Tensor:
    if key not in batch:
        raise ValueError(f"missing input feature '{key}'; the batch has {sorted(batch)}")
    return batch[key]
