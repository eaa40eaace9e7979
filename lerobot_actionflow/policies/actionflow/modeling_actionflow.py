"""ActionFlow as a LeRobot policy: batches in, SE(3) flow matching through the core out.

Training (Alg. 1): for a batch of observations and action chunks, draw ``q0`` in the current
EEF frame, a time ``t``, the point on the geodesic path and its local target velocities, and
regress the network's velocities onto them (translation errors in units of
``1 / translation_scale`` metres, so that the three terms have similar size).

Sampling (Alg. 2): ``K`` Euler steps on SE(3) from ``q0``; the chunk is returned as absolute
EEF targets ``[x, y, z, rot6d, gripper]``.
"""

from __future__ import annotations

from collections import deque

import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.policies.utils import populate_queues
from torch import Tensor

from lerobot_actionflow.flow import schedules
from lerobot_actionflow.flow import se3 as se3_flow
from lerobot_actionflow.geometry import check_finite, check_quaternion, quaternion_to_matrix
from lerobot_actionflow.nn import ActionFlowNetwork, IPASize, ObservationTokens, PoseAdaptation
from lerobot_actionflow.nn.image_encoder import ResNet18Encoder
from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig
from lerobot_actionflow.schema import ACTION_DIM, ACTION_KEY, POSE7_DIM, POSES_KEY, STATE_KEY
from lerobot_actionflow.schema.tensors import action_to_pose, pose_to_action


class ActionflowPolicy(PreTrainedPolicy):
    config_class = ActionflowConfig
    name = "actionflow"

    def __init__(self, config: ActionflowConfig, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config = config
        self.num_entities = config.poses_feature.shape[0]
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
        )
        self._compiled_sampler = None
        self.reset()

    # -- LeRobot API ------------------------------------------------------------------------------
    def get_optim_params(self):
        return self.parameters()

    def reset(self):
        """Clear the observation history and the action queue (call on env reset)."""
        keys = [POSES_KEY, *self.image_keys]
        if self.config.num_scalars:
            keys.append(STATE_KEY)
        self._queues = {k: deque(maxlen=self.config.n_obs_steps) for k in keys}
        self._queues[ACTION_KEY] = deque(maxlen=self.config.n_action_steps)

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict[str, float]]:
        """Flow-matching loss on a batch with ``observation.*`` ``(B, n_obs_steps, ...)`` and
        ``action`` ``(B, horizon, 10)``; returns the loss and its translation / rotation /
        gripper terms."""
        cfg = self.config
        obs = self._observation_tokens(batch)
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
            b, cfg.train_time_distribution, cfg.train_time_beta, dtype=action.dtype, device=action.device
        )
        x_t, u_t = se3_flow.geodesic_path(x0, x1, t)
        pred = self.network.velocity(encoded, x_t, t)

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
    def predict_action_chunk(
        self,
        batch: dict[str, Tensor],
        noise: se3_flow.LocalNoise | None = None,
        num_inference_steps: int | None = None,
    ) -> Tensor:
        """The sampled actions from the current step on: ``(B, horizon, 10)`` (the chunk starts at
        the current step; see :class:`ActionflowConfig`).

        Args:
            batch: the observation history ``(B, n_obs_steps, ...)``, oldest first (or
                ``(B, ...)`` when ``n_obs_steps == 1``).
            noise: initial noise in the EEF frame (drawn if None).
            num_inference_steps: Euler steps K (default: the config's); no retraining needed.
        """
        cfg = self.config
        obs = self._observation_tokens(batch)
        b = obs.p.shape[0]
        if noise is None:
            noise = se3_flow.draw_local_noise(
                b, cfg.horizon, cfg.noise_sigma, cfg.noise_rotation, cfg.noise_kappa, dtype=obs.p.dtype,
                device=obs.p.device,
            )  # fmt: skip
        k = num_inference_steps or cfg.num_inference_steps
        times = schedules.make_time_grid(
            k, cfg.time_spacing, cfg.time_spacing_rate, obs.p.dtype, obs.p.device
        )
        if self._use_compiled_sampler(obs.p.device):
            if self._compiled_sampler is None:
                self._compiled_sampler = self._compile_sampler(obs.p.device)
            # CUDA-graph replays reuse their output buffers: copy before anyone keeps a view.
            return self._compiled_sampler(
                obs.r, obs.p, obs.scalars, obs.image_features, noise.r, noise.p, noise.g, times
            ).clone()
        return self._sample(obs.r, obs.p, obs.scalars, obs.image_features, noise.r, noise.p, noise.g, times)

    def _compile_sampler(self, device: torch.device):
        """``torch.compile`` of :meth:`_sample`, one graph per K.

        On CUDA with ``compile_mode`` ("reduce-overhead": CUDA graphs). On the CPU, where a
        batch-1 chunk is bound by operator overhead and by streaming the weights, with inductor's
        ``freezing`` (weights folded in as constants and pre-packed for oneDNN's matmuls) and its
        C++ wrapper (kernels called from C++, not Python). Frozen weights are a snapshot: the
        compiled sampler is dropped whenever the weights may change (:meth:`train`,
        :meth:`load_state_dict`); code that edits parameters in place must call
        :meth:`reset_compiled_sampler`.
        """
        if device.type == "cpu":
            return torch.compile(self._sample, dynamic=False, options={"freezing": True, "cpp_wrapper": True})
        return torch.compile(self._sample, mode=self.config.compile_mode, dynamic=False)

    def reset_compiled_sampler(self) -> None:
        """Forget the compiled sampler; the next chunk compiles it again with the current weights."""
        self._compiled_sampler = None

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
        repeated at the start) and re-plans a chunk once ``n_action_steps`` have been used."""
        batch = {k: v for k, v in batch.items() if k in self._queues and k != ACTION_KEY}
        self._queues = populate_queues(self._queues, batch)
        if not self._queues[ACTION_KEY]:
            stacked = {k: torch.stack(list(q), dim=1) for k, q in self._queues.items() if k != ACTION_KEY}
            actions = self.predict_action_chunk(stacked, noise=noise)
            self._queues[ACTION_KEY].extend(actions[:, : self.config.n_action_steps].transpose(0, 1))
        return self._queues[ACTION_KEY].popleft()

    # -- internals ---------------------------------------------------------------------------------
    def _sample(self, obs_r, obs_p, scalars, image_features, noise_r, noise_p, noise_g, times) -> Tensor:
        """The whole K-step sampler as one tensor-in/tensor-out function (what gets compiled)."""
        obs = ObservationTokens(obs_r, obs_p, scalars, image_features)
        encoded = self.network.encode_observations(obs)
        noise = se3_flow.LocalNoise(noise_r, noise_p, noise_g)
        x0 = se3_flow.noise_to_world(noise, encoded.r_ref, encoded.p_ref)
        # Every flow time of the chunk is known: condition all K steps with one call per block.
        shifts = self.network.time_shifts(times[:-1])  # depth x (K, C)

        def velocity(x: se3_flow.PoseChunk, k: int) -> se3_flow.PoseVelocity:
            return self.network.velocity(encoded, x, shifts=[s[k : k + 1] for s in shifts])

        x1 = se3_flow.euler_sample(velocity, x0, times)
        return pose_to_action(x1.r, x1.p, x1.g.clamp(-1.0, 1.0))

    def _observation_tokens(self, batch: dict[str, Tensor]) -> ObservationTokens:
        """Validate the observation part of a batch and turn it into network inputs."""
        cfg = self.config
        poses = _require(batch, POSES_KEY)
        if poses.ndim == 3 and cfg.n_obs_steps == 1:
            poses = poses[:, None]
        expected = f"(B, {cfg.n_obs_steps}, {self.num_entities}, {POSE7_DIM})"
        if poses.ndim != 4 or poses.shape[1:] != (cfg.n_obs_steps, self.num_entities, POSE7_DIM):
            raise ValueError(f"'{POSES_KEY}' must have shape {expected}, got {tuple(poses.shape)}")
        check_finite(poses, POSES_KEY)
        quat = check_quaternion(poses[..., 3:], atol=cfg.rotation_tolerance, name=POSES_KEY)
        r, p = quaternion_to_matrix(quat), poses[..., :3]
        b = poses.shape[0]

        scalars = None
        if cfg.num_scalars:
            state = _require(batch, STATE_KEY)
            if state.ndim == 2 and cfg.n_obs_steps == 1:
                state = state[:, None]
            if state.ndim != 3 or state.shape[:2] != (b, cfg.n_obs_steps):
                raise ValueError(
                    f"'{STATE_KEY}' must have shape (B, {cfg.n_obs_steps}, D) with B={b}, "
                    f"got {tuple(state.shape)}"
                )
            check_finite(state, STATE_KEY)
            eef_scalars = state[..., list(cfg.state_scalar_indices)] * cfg.state_scalar_scale
            scalars = torch.zeros(
                b, cfg.n_obs_steps, self.num_entities, cfg.num_scalars, dtype=r.dtype, device=r.device
            )
            scalars[:, :, 0] = eef_scalars

        image_features = None
        if self.image_keys:
            feats = []
            for key in self.image_keys:
                img = _require(batch, key)
                if img.ndim == 4 and cfg.n_obs_steps == 1:
                    img = img[:, None]
                c = cfg.image_features[key].shape[0]
                if img.ndim != 5 or img.shape[:3] != (b, cfg.n_obs_steps, c):
                    raise ValueError(
                        f"'{key}' must have shape (B, {cfg.n_obs_steps}, {c}, H, W), got {tuple(img.shape)}"
                    )
                check_finite(img, key)
                f = self.image_encoder(img.flatten(0, 1)).view(b, cfg.n_obs_steps, -1)
                feats.append(f)
            image_features = torch.stack(feats, 2)
        return ObservationTokens(r, p, scalars, image_features)


def _require(batch: dict[str, Tensor], key: str) -> Tensor:
    if key not in batch:
        raise ValueError(f"missing input feature '{key}'; the batch has {sorted(batch)}")
    return batch[key]
