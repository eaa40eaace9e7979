"""Configuration of ``euclidean_flow``: Diffusion Policy with its diffusion process replaced by
a rectified linear flow (ActionFlow paper, App. B and E).

Observation inputs (any of them, at least one): ``observation.state`` ``(S_dim,)``,
``observation.environment_state`` ``(E_dim,)``, ``observation.images.<camera>`` ``(3, H, W)``,
and the point cloud named by ``point_cloud_key`` ``(M, 3)``. Other observation keys (e.g.
``observation.poses``) are ignored. Output: ``action`` ``(A,)``,
min-max normalised to ``[-1, 1]`` like Diffusion Policy.

Inference knobs that need no retraining (they are read at every call, and can be overridden per
call or with ``--policy.num_inference_steps=...`` on ``lerobot-eval``): ``num_inference_steps``
(``K`` integration steps), ``solver`` (``"euler"``: ``K`` network calls; ``"midpoint"``: ``2K``,
second order; real-time chunking needs ``"euler"``), ``time_spacing`` (``"uniform"`` or
``"exponential"``) and ``time_spacing_rate``.

The UNet fields carry the same names and defaults as LeRobot's ``DiffusionConfig``, because the
UNet backbone *is* LeRobot's ``DiffusionConditionalUnet1d``, built from this config; likewise the
vision fields feed LeRobot's ``DiffusionRgbEncoder``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import NormalizationMode, PreTrainedConfig
from lerobot.configs.types import FeatureType
from lerobot.optim import AdamConfig, DiffuserSchedulerConfig
from lerobot.utils.constants import ACTION

from lerobot_actionflow.policies.config_errors import (
    require,
    require_choice,
    require_ints,
    require_positive,
    require_probability,
)
from lerobot_actionflow.policies.execution import RealTimeExecutionConfig
from lerobot_actionflow.policies.flow_options import validate_solver_field, validate_train_time_fields
from lerobot_actionflow.policies.point_cloud_inputs import (
    check_point_cloud_feature,
    validate_point_cloud_fields,
)
from lerobot_actionflow.policies.wrist_focus import (
    WRIST_FOCUS_THRESHOLD,
    check_wrist_focus_features,
    validate_wrist_focus_fields,
)
from lerobot_actionflow.schema import ACTION_DIM, ENV_STATE_KEY, STATE_KEY, image_key

BACKBONES = ("transformer", "unet")
TIME_SPACINGS = ("uniform", "exponential")


@PreTrainedConfig.register_subclass("euclidean_flow")
@dataclass
class EuclideanFlowConfig(PreTrainedConfig, RealTimeExecutionConfig):
    """Rectified-flow policy on flat action chunks.

    Chunking (as Diffusion Policy): the network sees ``n_obs_steps`` observations and generates
    ``horizon`` actions starting at the oldest observation, so that the UNet backbone trains on
    exactly the targets of LeRobot's ``diffusion``; ``predict_action_chunk`` returns the
    ``horizon - n_obs_steps + 1`` of them from the current step on (as ``actionflow`` does), and
    ``n_action_steps <= horizon - n_obs_steps + 1`` of those are executed per chunk.

    Flow: ``a_t = t a_1 + (1 - t) a_0``, ``a_0 ~ N(0, I)``, target ``u = a_1 - a_0``, loss
    ``||v_theta(a_t, t, o) - u||^2``, ``t ~ U[0, 1]`` (or ``Beta``); sampling by ``K`` Euler
    steps on a uniform or exponentially spaced grid. The network sees ``time_embed_scale * t``.

    Point clouds (``point_cloud_key``, e.g. ``observation.point_cloud``; None: off): each
    observation step's cloud, in the world/base frame and metres (never normalised), goes
    through a PointNet (:class:`lerobot_actionflow.nn.pointnet.PointNetEncoder`: shared MLP of
    ``point_cloud_width`` units per point times ``point_cloud_scale``, max over the points, then
    ``point_cloud_feature_dim`` features) whose output joins that step's conditioning. Nothing
    is centred or rotated: this is the non-equivariant baseline.

    ``use_environment_state=False`` ignores ``observation.environment_state`` (the object poses)
    even when the dataset has it: a point-cloud policy then sees the objects only in the cloud.

    Wrist focus (App. G.3): ``wrist_focus_camera``, ``wrist_focus_size``,
    ``wrist_focus_threshold``, as in ``actionflow``
    (:mod:`lerobot_actionflow.policies.wrist_focus`).

    Execution in real time (App. G), applied by ``select_action``: the fields of
    :class:`lerobot_actionflow.policies.execution.RealTimeExecutionConfig`, as in ``actionflow``
    (the defaults: no skipping, no smoothing, guidance toward the previous chunk with Euler).
    Smoothing blends rotations along the SE(3) geodesic, so it needs actions that are absolute
    EEF poses ``[x y z rot6d gripper]`` in their own units: a 10-D action with
    ``normalization_mapping["ACTION"] = IDENTITY``. With min-max normalised actions, apply
    :class:`lerobot_actionflow.policies.execution.TargetSmoother` to the postprocessed actions
    instead.
    """

    # Inputs / output structure.
    n_obs_steps: int = 2
    horizon: int = 16
    n_action_steps: int = 8
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.MEAN_STD,
            "STATE": NormalizationMode.MIN_MAX,
            "ENV": NormalizationMode.MIN_MAX,
            "ACTION": NormalizationMode.MIN_MAX,
        }
    )
    # Training samples whose chunk would run this far past the episode end are not drawn.
    drop_n_last_frames: int = 7

    # Backbone of the velocity field.
    backbone: str = "transformer"
    # Transformer (Diffusion Policy's transformer defaults).
    n_layer: int = 8
    n_head: int = 4
    n_emb: int = 256
    p_drop_emb: float = 0.0
    p_drop_attn: float = 0.1
    causal_attn: bool = True
    # UNet: LeRobot's DiffusionConditionalUnet1d (same names and defaults as DiffusionConfig).
    down_dims: tuple[int, ...] = (512, 1024, 2048)
    kernel_size: int = 5
    n_groups: int = 8
    diffusion_step_embed_dim: int = 128
    use_film_scale_modulation: bool = True
    gradient_checkpointing: bool = False
    # Flow time t in [0, 1] enters both backbones' sinusoidal embeddings as time_embed_scale * t.
    time_embed_scale: float = 1000.0

    # Vision (LeRobot's DiffusionRgbEncoder). No pretrained weights by default: everything runs
    # offline; group norm is then Diffusion Policy's choice.
    vision_backbone: str = "resnet18"
    resize_shape: tuple[int, int] | None = None
    crop_ratio: float = 1.0
    crop_shape: tuple[int, int] | None = None
    crop_is_random: bool = True
    pretrained_backbone_weights: str | None = None
    use_group_norm: bool = True
    spatial_softmax_num_keypoints: int = 32
    use_separate_rgb_encoder_per_camera: bool = True

    # False: ignore observation.environment_state (the object poses) even when the dataset has it,
    # e.g. so that a point-cloud policy sees the objects only through the cloud.
    use_environment_state: bool = True
    # Point cloud (None: off): a PointNet global feature per observation step.
    point_cloud_key: str | None = None
    point_cloud_width: int = 128
    point_cloud_feature_dim: int = 128
    point_cloud_scale: float = 10.0

    # App. G.3: black out the wrist image outside its centre once the gripper is closed.
    wrist_focus_camera: str | None = None
    wrist_focus_size: int = 30
    wrist_focus_threshold: float = WRIST_FOCUS_THRESHOLD

    # Flow matching.
    train_time_distribution: str = "uniform"
    train_time_beta: tuple[float, float] = (1.5, 1.0)
    # "logit_normal": t = sigmoid(N(mean, std^2)) with (mean, std) = train_time_logit_normal.
    train_time_logit_normal: tuple[float, float] = (0.0, 1.0)
    num_inference_steps: int = 10
    solver: str = "euler"
    time_spacing: str = "exponential"
    time_spacing_rate: float = 2.0
    # Clip the generated (normalised) chunk to [-1, 1], the range of min-max normalised actions.
    clip_sample: bool = True
    do_mask_loss_for_padding: bool = False

    # Training presets (LeRobot's Diffusion Policy values).
    optimizer_lr: float = 1e-4
    optimizer_betas: tuple[float, float] = (0.95, 0.999)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-6
    scheduler_name: str = "cosine"
    scheduler_warmup_steps: int = 500

    def __post_init__(self):
        super().__post_init__()
        self.validate_values()
        if self.resize_shape is not None:
            self.crop_shape = (
                (int(self.resize_shape[0] * self.crop_ratio), int(self.resize_shape[1] * self.crop_ratio))
                if self.crop_ratio < 1.0
                else None
            )

    def validate_values(self) -> None:
        """Refuse values the policy cannot work with (:class:`PolicyConfigError`, a ``ValueError``,
        whose message ``lerobot-train`` prints; see :mod:`lerobot_actionflow.policies.config_errors`).
        """
        require_choice(self, "backbone", BACKBONES)
        require_choice(self, "time_spacing", TIME_SPACINGS)
        validate_train_time_fields(self)
        validate_solver_field(self)
        require_ints(self, ("num_inference_steps", "n_obs_steps", "horizon", "n_action_steps"))
        require(
            self.n_action_steps <= self.horizon - self.n_obs_steps + 1,
            "`n_action_steps` must be <= horizon - n_obs_steps + 1 (actions start at the oldest "
            f"observation); got {self.n_action_steps=}, {self.horizon=}, {self.n_obs_steps=}",
        )
        require_ints(self, ("drop_n_last_frames",), minimum=0)
        require_positive(self, ("time_spacing_rate", "time_embed_scale"))
        if self.backbone == "transformer":
            require_ints(self, ("n_layer", "n_head", "n_emb"))
            require(
                self.n_emb % self.n_head == 0,
                f"`n_emb` ({self.n_emb}) must be divisible by `n_head` ({self.n_head})",
            )
            require(
                self.n_emb % 2 == 0 and self.n_emb >= 4,
                f"`n_emb` must be even and >= 4 (sinusoidal time embedding), got {self.n_emb}",
            )
            require_probability(self, ("p_drop_emb", "p_drop_attn"))
        else:
            require_ints(self, ("kernel_size", "n_groups"))
            require(self.kernel_size % 2 == 1, f"`kernel_size` must be odd, got {self.kernel_size}")
            require(
                len(self.down_dims) >= 1
                and all(isinstance(d, int) and d >= 1 and d % self.n_groups == 0 for d in self.down_dims),
                f"`down_dims` must be channel counts >= 1, each divisible by n_groups={self.n_groups} "
                f"(group norm), got {self.down_dims!r}",
            )
            require(
                isinstance(self.diffusion_step_embed_dim, int)
                and self.diffusion_step_embed_dim % 2 == 0
                and self.diffusion_step_embed_dim >= 4,
                "`diffusion_step_embed_dim` must be even and >= 4 (sinusoidal time embedding), "
                f"got {self.diffusion_step_embed_dim!r}",
            )
            factor = 2 ** (len(self.down_dims) - 1)
            require(
                self.horizon % factor == 0,
                f"the UNet halves the horizon {len(self.down_dims) - 1} times: `horizon` must be a "
                f"multiple of {factor}, got {self.horizon} with down_dims={self.down_dims}",
            )
        require(
            self.vision_backbone.startswith("resnet"),
            f"`vision_backbone` must be a torchvision ResNet, got {self.vision_backbone!r}",
        )
        require(0 < self.crop_ratio <= 1.0, f"`crop_ratio` must be in (0, 1], got {self.crop_ratio}")
        require_ints(self, ("spatial_softmax_num_keypoints",))
        self.validate_execution()
        validate_point_cloud_fields(self, ("point_cloud_width", "point_cloud_feature_dim"))
        require_positive(self, ("point_cloud_scale",))
        validate_wrist_focus_fields(self)

    def get_optimizer_preset(self) -> AdamConfig:
        return AdamConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
        )

    def get_scheduler_preset(self) -> DiffuserSchedulerConfig:
        return DiffuserSchedulerConfig(name=self.scheduler_name, num_warmup_steps=self.scheduler_warmup_steps)

    def validate_features(self) -> None:
        action = self.action_feature
        if action is None or len(action.shape) != 1:
            raise ValueError(
                f"euclidean_flow needs an output feature '{ACTION}' of shape (action_dim,), "
                f"got {None if action is None else tuple(action.shape)}"
            )
        check_point_cloud_feature(self.input_features, self.point_cloud_key, 1)
        if (
            self.robot_state_feature is None
            and self.read_env_state_feature is None
            and not self.image_features
            and self.point_cloud_key is None
        ):
            raise ValueError(
                f"euclidean_flow needs at least one observation input: '{STATE_KEY}' (state_dim,), "
                f"'{ENV_STATE_KEY}' (env_dim,), '{image_key('<camera>')}' (3, H, W) or a point cloud "
                f"(point_cloud_key); got input features {sorted(self.input_features or {})}"
            )
        check_wrist_focus_features(self)
        for key, ft in self.used_input_features.items():
            if key == self.point_cloud_key:
                continue  # checked above: (M, 3)
            if ft.type is FeatureType.VISUAL:
                if len(ft.shape) != 3:
                    raise ValueError(
                        f"image feature '{key}' must have shape (3, H, W), got {tuple(ft.shape)}"
                    )
            elif len(ft.shape) != 1:
                raise ValueError(f"feature '{key}' must be a flat vector (dim,), got {tuple(ft.shape)}")
        if self.target_smoothing < 1:
            mode = self.normalization_mapping.get("ACTION", NormalizationMode.IDENTITY)
            if tuple(action.shape) != (ACTION_DIM,) or mode is not NormalizationMode.IDENTITY:
                raise ValueError(
                    f"target_smoothing={self.target_smoothing} blends absolute EEF poses along SE(3) "
                    f"geodesics: it needs a ({ACTION_DIM},) '{ACTION}' [x y z rot6d gripper] with "
                    f"normalization_mapping['ACTION'] = IDENTITY, got shape {tuple(action.shape)} and "
                    f"{mode}; for normalised actions apply execution.TargetSmoother after the postprocessor"
                )
        shapes = {tuple(ft.shape) for ft in self.image_features.values()}
        if len(shapes) > 1:
            raise ValueError(f"all camera images must have the same shape, got {sorted(shapes)}")

    @property
    def read_env_state_feature(self):
        """``observation.environment_state`` when the policy reads it (``use_environment_state``)."""
        return self.env_state_feature if self.use_environment_state else None

    @property
    def used_input_features(self) -> dict:
        """The observation features the policy reads: images, state, environment state, and the
        point cloud when ``point_cloud_key`` is set."""
        used = {key: ft for key, ft in self.image_features.items()}
        for key, ft in (self.input_features or {}).items():
            if ft is self.robot_state_feature or (ft is self.read_env_state_feature and ft is not None):
                used[key] = ft
        if self.point_cloud_key is not None and self.point_cloud_key in (self.input_features or {}):
            used[self.point_cloud_key] = self.input_features[self.point_cloud_key]
        return used

    @property
    def observation_delta_indices(self) -> list:
        return list(range(1 - self.n_obs_steps, 1))

    @property
    def action_delta_indices(self) -> list:
        return list(range(1 - self.n_obs_steps, 1 - self.n_obs_steps + self.horizon))

    @property
    def reward_delta_indices(self) -> None:
        return None
