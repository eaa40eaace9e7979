"""Configuration of the ActionFlow policy (LeRobot policy type ``actionflow``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, NormalizationMode
from lerobot.optim.optimizers import AdamWConfig
from lerobot.optim.schedulers import CosineAnnealingWithWarmupSchedulerConfig

from lerobot_actionflow.nn.actionflow_network import TRANSLATION_FRAMES
from lerobot_actionflow.policies.config_errors import (
    require,
    require_choice,
    require_ints,
    require_non_negative,
    require_positive,
    require_probability,
)
from lerobot_actionflow.policies.execution import RealTimeExecutionConfig
from lerobot_actionflow.policies.flow_options import (
    validate_few_step_fields,
    validate_solver_field,
    validate_train_time_fields,
)
from lerobot_actionflow.policies.point_cloud_inputs import (
    check_point_cloud_feature,
    validate_point_cloud_fields,
)
from lerobot_actionflow.policies.wrist_focus import (
    WRIST_FOCUS_THRESHOLD,
    check_wrist_focus_features,
    validate_wrist_focus_fields,
)
from lerobot_actionflow.schema import (
    ACTION_DIM,
    ACTION_KEY,
    POSE7_DIM,
    POSES_KEY,
    STATE_GRIPPER_INDICES,
    STATE_KEY,
)


@PreTrainedConfig.register_subclass("actionflow")
@dataclass
class ActionflowConfig(PreTrainedConfig, RealTimeExecutionConfig):
    """ActionFlow: SE(3) flow matching on end-effector action poses with an IPA transformer.

    Inputs: ``observation.poses`` ``(N, 7)`` (required; row 0 the end-effector), optional
    ``observation.state`` (only the invariant entries named by ``state_scalar_indices``, e.g.
    the gripper opening, are used) and optional images. Output: ``action`` ``(10,)`` =
    absolute EEF target ``[x, y, z, rot6d, gripper]``.

    Poses and actions are never mean/std normalised (that would break equivariance); the
    network's adaptation module handles scale instead. ``observation.poses`` is a STATE feature
    to LeRobot, and LeRobot re-applies ``normalization_mapping`` to every feature when it reloads
    processors (``--resume``, ``--policy.path``), so STATE and ACTION must map to IDENTITY: the
    config refuses anything else.

    Attributes (the paper's values in brackets where it gives them):
        n_obs_steps: observation history [5 on the real robot; 2 here by default].
        horizon: action chunk length [16].
        n_action_steps: actions executed per chunk before re-planning.

    Chunking: the ``horizon`` actions start at the current step (``action_delta_indices`` 0 ..
    horizon - 1), and ``predict_action_chunk`` returns all of them. The action tokens are posed
    at the actions they stand for, relative to the current EEF, and actions of past steps would
    only spend tokens on what was already executed. ``euclidean_flow`` samples from the oldest
    observation step, like LeRobot's ``diffusion``, and drops the past steps when it returns a
    chunk, so both policies' ``predict_action_chunk`` return the actions from the current step on.
        state_scalar_indices: entries of ``observation.state`` fed to the EEF token as
            invariant scalars (default: the two gripper finger positions of the schema), times
            ``state_scalar_scale`` (Panda finger positions are within 0.04 m: 25 brings them to ~1).
        camera_entities: for each image feature, in ``input_features`` order, the entity slot
            whose pose carries that camera's token (0 = EEF, right for a wrist camera). Empty:
            every camera on the EEF.
        dim, num_layers [4], num_heads, head_dim, num_query_points, num_value_points,
            mlp_ratio, dropout: the SE(3)-invariant transformer.
        adaptation_frame, translation_scale [10], squash_translations [tanh]: App. F.2. The
            scale also sets the unit of the translation loss (velocity errors times
            ``translation_scale``, squared), so a scale s weights translations (s / 10)^2 as
            much as the default; ``loss_weight_translation = (10 / s)^2`` restores the weight.
        translation_velocity_frame: the frame of the network's translation velocity: ``"pose"``
            [App. C], the body frame of the current action pose, or ``"eef"``, the EEF frame of
            the latest observation, in which the regression target is constant along the path
            (:mod:`lerobot_actionflow.nn.actionflow_network`). Both are exactly equivariant.
        noise_sigma: std of the initial translation noise around the EEF (metres).
        noise_rotation: ``"concentrated"`` [default] (around the EEF orientation,
            ``Exp(noise_kappa * eps)``, ``eps ~ N(0, I)``) or ``"uniform"`` (Haar on SO(3), the
            paper's). With concentrated initial rotations 2 Euler steps score as 10 do on Lift
            and StackThree_D0 (benchmarks/RESULTS.md, "Few-step sampling").
        num_inference_steps [4]: integration steps K; may be changed at inference time.
        solver: ``"euler"`` [Eq. 8] or ``"midpoint"`` (second-order Runge-Kutta-Munthe-Kaas on
            SE(3), :func:`lerobot_actionflow.flow.se3.midpoint_step`). Network calls per chunk:
            K with Euler, 2K with midpoint (``evaluation.sweep`` counts calls, so IS = 2K there).
            Real-time chunking guidance integrates with Euler and refuses ``"midpoint"``.
        few_step_objective: ``"none"`` (plain flow matching) or ``"shortcut"``
            (:mod:`lerobot_actionflow.flow.shortcut`): the network also takes the step size ``d``
            (an embedding added to the time conditioning), and a fraction ``shortcut_fraction``
            of every batch regresses ``v(x_t, t, 2d)`` onto the SE(3) composition of two of the
            model's own steps of size ``d`` (``2d = 2^-j`` down to ``2 / shortcut_max_steps``);
            the rest is flow matching at ``d = 0``. Sampling with K steps conditions on
            ``d = 1/K`` (0 for ``K >= shortcut_max_steps``); it needs the uniform time grid and
            the Euler solver. Training cost: two extra no-grad network passes on the shortcut
            fraction of the batch (+40% per training step at 0.25, measured at the CPU size,
            batch 64, no images). Exactly equivariant, like
            flow matching.
        time_spacing: ``"uniform"`` or ``"exponential"`` (App. E), with ``time_spacing_rate``.
        train_time_distribution: ``"uniform"``, ``"beta"`` (``train_time_beta``) or
            ``"logit_normal"`` (``t = sigmoid(N(mean, std^2))``, ``train_time_logit_normal`` =
            ``(mean, std)``).
        loss_weight_*: weights of the translation / rotation / gripper velocity errors.
        image_size [80x80], image_encoder_weights: ResNet18 input size and an optional local
            weights file (never downloaded).
        pose_entities: the rows of ``observation.poses`` the policy reads, row 0 (the EEF)
            first; empty (default): all. E.g. ``(0, 1)`` hides the task's later objects, so
            that a policy sees one of them only through the point cloud.
        point_cloud_key: an input feature ``(M, 3)`` (e.g. ``observation.point_cloud``: points
            in the world/base frame, metres) turned into ``point_cloud_groups`` tokens; None
            (default): no point tokens, even when the dataset has a cloud. Each token is a group
            of the ``point_cloud_group_size`` nearest points around a farthest-point-sampled
            centre (from the latest observation step), posed at (EEF rotation, centre), encoded
            by a PointNet of hidden width ``point_cloud_width`` over the offsets in that frame
            (:mod:`lerobot_actionflow.nn.point_tokens`); equivariance stays exact.
        point_cloud_prefix: read only the first N rows of the ``(M, 3)`` cloud, N <= M (the env's
            ``point_cloud_points`` stays the recorded M); None (default): all M. The
            clouds of :mod:`lerobot_actionflow.envs.point_cloud` are in farthest-point order, so
            their first N rows are their N-point FPS subsample: the number of points is a
            policy option, without recording the data again.
        wrist_focus_camera, wrist_focus_size, wrist_focus_threshold: the image trick of
            App. G.3 (:mod:`lerobot_actionflow.policies.wrist_focus`): once the gripper opening
            from ``observation.state`` is below the threshold (metres), the named camera's
            image is black outside its central ``wrist_focus_size`` square. None: off.
        compile_sampler: capture the whole K-step sampler with ``torch.compile``: on CUDA in mode
            ``compile_mode`` ("reduce-overhead" replays CUDA graphs), on the CPU with frozen,
            pre-packed weights and inductor's C++ wrapper (about 2.5x faster than eager at batch
            1; benchmarks/RESULTS.md). None (default): on when the policy runs on a CUDA device,
            off on the CPU, where the first chunk of every K compiles for 2-3 minutes. An
            artefact of ``actionflow-export`` stored with the checkpoint takes precedence
            (:mod:`lerobot_actionflow.policies.exported`).

    Execution in real time (App. G), applied by ``select_action``: the fields of
    :class:`lerobot_actionflow.policies.execution.RealTimeExecutionConfig`
    (``execution_delay_steps``, ``execution_delay_s``, ``measure_inference_delay``,
    ``control_period_s``, ``target_smoothing``, ``guide_to_previous_chunk``). By default
    nothing is skipped or smoothed, and each chunk after an episode's first is guided toward the
    previous one (with the Euler solver).
    The paper's "execute two actions, then re-plan" is ``n_action_steps=2``. For real-time
    chunking (``lerobot-rollout --inference.type=rtc``) see ``predict_action_chunk``.
    """

    n_obs_steps: int = 2
    horizon: int = 16
    n_action_steps: int = 8

    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.MEAN_STD,
            "STATE": NormalizationMode.IDENTITY,
            "ENV": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.IDENTITY,
        }
    )

    state_scalar_indices: tuple[int, ...] = STATE_GRIPPER_INDICES
    state_scalar_scale: float = 25.0
    camera_entities: tuple[int, ...] = ()

    dim: int = 128
    num_layers: int = 4
    num_heads: int = 8
    head_dim: int = 16
    num_query_points: int = 4
    num_value_points: int = 8
    mlp_ratio: float = 2.0
    dropout: float = 0.0

    adaptation_frame: str = "eef"
    translation_scale: float = 10.0
    squash_translations: bool = True
    translation_velocity_frame: str = "pose"

    noise_sigma: float = 0.1
    noise_rotation: str = "concentrated"
    noise_kappa: float = 0.5
    num_inference_steps: int = 4
    solver: str = "euler"
    few_step_objective: str = "none"
    shortcut_fraction: float = 0.25
    shortcut_max_steps: int = 128
    time_spacing: str = "uniform"
    time_spacing_rate: float = 2.0
    train_time_distribution: str = "uniform"
    train_time_beta: tuple[float, float] = (1.5, 1.0)
    train_time_logit_normal: tuple[float, float] = (0.0, 1.0)

    loss_weight_translation: float = 1.0
    loss_weight_rotation: float = 1.0
    loss_weight_gripper: float = 1.0

    image_size: tuple[int, int] | None = (80, 80)
    image_encoder_weights: str | None = None

    pose_entities: tuple[int, ...] = ()
    point_cloud_key: str | None = None
    point_cloud_groups: int = 32
    point_cloud_group_size: int = 16
    point_cloud_width: int = 64
    point_cloud_prefix: int | None = None

    wrist_focus_camera: str | None = None
    wrist_focus_size: int = 30
    wrist_focus_threshold: float = WRIST_FOCUS_THRESHOLD

    rotation_tolerance: float = 1e-2

    compile_sampler: bool | None = None
    compile_mode: str = "reduce-overhead"

    optimizer_lr: float = 1e-4
    optimizer_betas: tuple[float, float] = (0.9, 0.999)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-4
    optimizer_grad_clip_norm: float = 1.0
    scheduler_warmup_steps: int = 500

    def __post_init__(self):
        super().__post_init__()
        self.validate_values()

    def validate_values(self) -> None:
        """Refuse values the policy cannot work with (:class:`PolicyConfigError`, a ``ValueError``,
        whose message ``lerobot-train`` prints; see :mod:`lerobot_actionflow.policies.config_errors`).
        """
        require_ints(self, ("n_obs_steps", "horizon", "n_action_steps"))
        require(
            self.n_action_steps <= self.horizon,
            f"`n_action_steps` must be in 1..horizon={self.horizon}, got {self.n_action_steps}",
        )
        no_obs = " (the actions would not depend on the observation)"
        require_ints(self, ("num_layers", "dim", "num_heads", "head_dim"), why=no_obs)
        require(self.dim % 2 == 0, f"`dim` must be even (sinusoidal time embedding), got {self.dim}")
        require_ints(self, ("num_query_points", "num_value_points"))
        require_positive(self, ("mlp_ratio", "translation_scale", "noise_sigma", "rotation_tolerance"))
        require_probability(self, ("dropout",))
        require_choice(self, "adaptation_frame", ("eef", "world"))
        require(
            not (self.squash_translations and self.adaptation_frame == "world"),
            "`squash_translations` needs adaptation_frame='eef': tanh squashing of world-frame "
            "translations would break equivariance",
        )
        require_choice(self, "translation_velocity_frame", TRANSLATION_FRAMES)
        require_choice(self, "noise_rotation", ("uniform", "concentrated"))
        require_positive(self, ("noise_kappa",))
        require_ints(self, ("num_inference_steps",))
        require_choice(self, "time_spacing", ("uniform", "exponential"))
        require_positive(self, ("time_spacing_rate",))
        validate_train_time_fields(self)
        validate_solver_field(self)
        validate_few_step_fields(self)
        weights = ("loss_weight_translation", "loss_weight_rotation", "loss_weight_gripper")
        require_non_negative(self, weights)
        require(any(getattr(self, w) > 0 for w in weights), f"at least one of {weights} must be > 0")
        require(
            all(isinstance(i, int) and i >= 0 for i in self.state_scalar_indices),
            f"`state_scalar_indices` must be indices >= 0, got {self.state_scalar_indices!r}",
        )
        require(
            all(isinstance(e, int) and e >= 0 for e in self.camera_entities),
            f"`camera_entities` must be entity indices >= 0, got {self.camera_entities!r}",
        )
        require(
            self.image_size is None or (len(self.image_size) == 2 and min(self.image_size) >= 1),
            f"`image_size` must be (height, width) >= 1, got {self.image_size!r}",
        )
        self.validate_execution()
        require(
            not self.pose_entities
            or (
                self.pose_entities[0] == 0
                and all(isinstance(e, int) and e >= 0 for e in self.pose_entities)
                and len(set(self.pose_entities)) == len(self.pose_entities)
            ),
            "`pose_entities` must be distinct row indices starting with 0 (the EEF), "
            f"got {self.pose_entities!r}",
        )
        validate_point_cloud_fields(
            self, ("point_cloud_groups", "point_cloud_group_size", "point_cloud_width")
        )
        if self.point_cloud_prefix is not None:
            require(
                self.point_cloud_key is not None,
                f"`point_cloud_prefix` is {self.point_cloud_prefix!r} but `point_cloud_key` is None: "
                "name the cloud to read, or leave point_cloud_prefix unset",
            )
            require_ints(
                self,
                ("point_cloud_prefix",),
                max(self.point_cloud_groups, self.point_cloud_group_size),
                "; it must cover point_cloud_groups and point_cloud_group_size (None reads all M points)",
            )
        validate_wrist_focus_fields(self)
        for kind in ("STATE", "ACTION"):
            mode = self.normalization_mapping.get(kind, NormalizationMode.IDENTITY)
            require(
                mode is NormalizationMode.IDENTITY,
                f"normalization_mapping['{kind}'] must be IDENTITY for actionflow, got {mode}: "
                f"{POSES_KEY} and {ACTION_KEY} are poses, and normalising them breaks SE(3) equivariance",
            )

    # -- LeRobot hooks -------------------------------------------------------------------------
    @property
    def observation_delta_indices(self) -> list[int]:
        return list(range(1 - self.n_obs_steps, 1))

    @property
    def action_delta_indices(self) -> list[int]:
        # The chunk starts at the current step.
        return list(range(self.horizon))

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> AdamWConfig:
        return AdamWConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> CosineAnnealingWithWarmupSchedulerConfig:
        # Linear warm-up, then cosine annealing over the rest of the run (--steps).
        return CosineAnnealingWithWarmupSchedulerConfig(num_warmup_steps=self.scheduler_warmup_steps)

    @property
    def poses_feature(self):
        return (self.input_features or {}).get(POSES_KEY)

    def validate_features(self) -> None:
        """Refuse a feature set the policy cannot use, naming the feature and shape."""
        ft = self.poses_feature
        if ft is None:
            raise ValueError(
                f"actionflow needs the input feature '{POSES_KEY}' (N, {POSE7_DIM}) [x y z qw qx qy qz], "
                f"row 0 the end-effector; got input features {sorted(self.input_features or {})}"
            )
        if len(ft.shape) != 2 or ft.shape[1] != POSE7_DIM or ft.shape[0] < 1:
            raise ValueError(f"'{POSES_KEY}' must have shape (N, {POSE7_DIM}), got {tuple(ft.shape)}")
        act = self.action_feature
        if act is None:
            raise ValueError(f"actionflow needs the output feature '{ACTION_KEY}' ({ACTION_DIM},)")
        if tuple(act.shape) != (ACTION_DIM,):
            raise ValueError(
                f"'{ACTION_KEY}' must have shape ({ACTION_DIM},) [x y z rot6d(6) gripper], "
                f"got {tuple(act.shape)}"
            )
        bad_rows = [e for e in self.pose_entities if e >= ft.shape[0]]
        if bad_rows:
            raise ValueError(f"pose_entities {bad_rows} are outside the {ft.shape[0]} rows of '{POSES_KEY}'")
        state = self.robot_state_feature
        if state is not None and self.state_scalar_indices:
            bad = [i for i in self.state_scalar_indices if not 0 <= i < state.shape[0]]
            if bad:
                raise ValueError(
                    f"state_scalar_indices {bad} are outside '{STATE_KEY}' of shape {tuple(state.shape)}"
                )
        n_cam = len(self.image_features)
        if self.camera_entities and len(self.camera_entities) != n_cam:
            raise ValueError(
                f"camera_entities has {len(self.camera_entities)} entries for {n_cam} image features "
                f"{list(self.image_features)}"
            )
        n_read = len(self.pose_entities) or ft.shape[0]
        for e in self.camera_entities:
            if not 0 <= e < n_read:
                raise ValueError(f"camera entity {e} is outside the {n_read} entities the policy reads")
        for key, img in self.image_features.items():
            if img.type is FeatureType.VISUAL and len(img.shape) != 3:
                raise ValueError(f"image feature '{key}' must be (C, H, W), got {tuple(img.shape)}")
        check_point_cloud_feature(
            self.input_features,
            self.point_cloud_key,
            self.point_cloud_prefix or max(self.point_cloud_groups, self.point_cloud_group_size),
        )
        check_wrist_focus_features(self)

    @property
    def point_cloud_feature(self):
        """The point-cloud input feature the policy reads, or None."""
        return None if self.point_cloud_key is None else (self.input_features or {}).get(self.point_cloud_key)

    @property
    def num_scalars(self) -> int:
        return len(self.state_scalar_indices) if self.robot_state_feature is not None else 0
