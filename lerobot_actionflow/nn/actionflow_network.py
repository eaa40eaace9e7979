"""ActionFlow's velocity field ``v_theta(T_k, T_o, F_o, t)``: posed tokens through the
SE(3)-invariant transformer (App. C, D, F, G).

Tokens (``L = H_o N + H_o N_cam + G + H``):

* observation entities, for each of the ``H_o`` history steps and ``N`` entity slots: pose
  ``T_{h,e}``, feature ``E_entity[e] + E_history[h] + Linear(scalars_{h,e})`` (per-entity
  invariant scalars, e.g. the gripper opening for the end-effector);
* camera features (optional): ResNet18 features projected to ``C``, plus ``E_camera[c] +
  E_history[h]``, posed at the entity that carries the camera (the EEF for a wrist camera);
* point-cloud groups (optional; :mod:`lerobot_actionflow.nn.point_tokens`): ``G`` tokens from
  the latest step's cloud, posed at (EEF rotation, group centre), feature a PointNet of the
  group's offsets in that frame plus ``E_points``;
* action tokens, for each of the ``H`` horizon steps: the current (noisy) pose ``T_k`` and
  feature ``E_step[k] + Linear(g_k)``.

All poses pass through the adaptation module (reference: the EEF at the latest observation
step) and are centred on the mean observation position (a global translation: nothing changes
mathematically, float32 stays exact). Observation tokens attend among themselves and do not
see flow time, so they are encoded once per chunk and cached (``encode_observations``); the
action tokens, conditioned on ``t``, attend to that cache and to each other at every step
(``velocity``). Each action token reads out its local translation velocity ``v_p``, rotation
velocity ``v_r`` and gripper velocity ``v_g``.
Velocities are returned in the action token's own frame (what the SE(3) Euler step takes), ``v_p``
in metres per unit time (the network's output divided by ``translation_scale``). The head's
translation output ``u`` is read in one of two frames (``translation_frame``):

* ``"pose"``: the token's own frame, ``v_p = u`` (App. C). The regression target
  ``r_t^T (p_1 - p_0)`` then turns with the rotation noise along the path.
* ``"eef"``: the reference (EEF) frame, ``v_p = r_t^T R_e u``. The target ``R_e^T (p_1 - p_0)`` is
  constant along the path, and the loss ``|v_p - r_t^T (p_1 - p_0)|`` equals
  ``|u - R_e^T (p_1 - p_0)|`` because ``r_t`` is a rotation. ``R_e`` moves with the scene, so the
  sampled poses stay equivariant.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from lerobot_actionflow.flow.se3 import PoseChunk, PoseVelocity
from lerobot_actionflow.nn.embeddings import SinusoidalTimeEmbedding
from lerobot_actionflow.nn.ipa import DEFAULT_IPA_SIZE, IPASize
from lerobot_actionflow.nn.point_tokens import PointGroupTokenizer
from lerobot_actionflow.nn.pose_adaptation import PoseAdaptation
from lerobot_actionflow.nn.se3_transformer import SE3InvariantTransformer

#: Frames the head's translation velocity can be read in; see the module docstring.
TRANSLATION_FRAMES = ("pose", "eef")


@dataclass
class ObservationTokens:
    """Observation input of the network.

    Attributes:
        r: entity rotations ``(B, H_o, N, 3, 3)``; p: positions ``(B, H_o, N, 3)``; row 0 the EEF.
        scalars: per-entity invariant scalars ``(B, H_o, N, S)`` or None.
        image_features: ``(B, H_o, N_cam, F)`` encoder outputs or None.
        points: the latest step's point cloud ``(B, M, 3)`` (world frame, metres) or None.
    """

    r: torch.Tensor
    p: torch.Tensor
    scalars: torch.Tensor | None = None
    image_features: torch.Tensor | None = None
    points: torch.Tensor | None = None


@dataclass
class EncodedObservations:
    """What :meth:`ActionFlowNetwork.encode_observations` computes once per chunk.

    Attributes:
        r_ref, p_ref: the reference (EEF) frame ``(B, 3, 3)``, ``(B, 3)``.
        center: mean adapted observation position ``(B, 1, 3)``.
        context: per-block cached keys/values of the observation tokens.
    """

    r_ref: torch.Tensor
    p_ref: torch.Tensor
    center: torch.Tensor
    context: list[tuple[torch.Tensor, torch.Tensor]] = field(default_factory=list)

    def first(self, n: int) -> EncodedObservations:
        """The encoding of the first ``n`` samples of the batch."""
        return EncodedObservations(
            self.r_ref[:n], self.p_ref[:n], self.center[:n], [(k[:n], v[:n]) for k, v in self.context]
        )


class ActionFlowNetwork(nn.Module):
    def __init__(
        self,
        num_entities: int,
        n_obs_steps: int,
        horizon: int,
        num_scalars: int = 0,
        camera_entities: tuple[int, ...] = (),
        image_feature_dim: int = 512,
        size: IPASize = DEFAULT_IPA_SIZE,
        depth: int = 4,
        mlp_ratio: float = 2.0,
        dropout: float = 0.0,
        adaptation: PoseAdaptation | None = None,
        translation_frame: str = "pose",
        point_groups: int = 0,
        point_group_size: int = 16,
        point_width: int = 64,
        step_size_conditioning: bool = False,
    ):
        super().__init__()
        if translation_frame not in TRANSLATION_FRAMES:
            raise ValueError(
                f"translation_frame must be one of {TRANSLATION_FRAMES}, got {translation_frame!r}"
            )
        self.translation_frame = translation_frame
        dim = size.dim
        self.num_entities, self.n_obs_steps, self.horizon = num_entities, n_obs_steps, horizon
        self.num_scalars = num_scalars
        self.camera_entities = tuple(camera_entities)
        for e in self.camera_entities:
            if not 0 <= e < num_entities:
                raise ValueError(f"camera entity index {e} is outside 0..{num_entities - 1}")
        self.adaptation = adaptation if adaptation is not None else PoseAdaptation()
        self.entity_embed = nn.Parameter(torch.randn(num_entities, dim) * 0.02)
        self.history_embed = nn.Parameter(torch.randn(n_obs_steps, dim) * 0.02)
        self.step_embed = nn.Parameter(torch.randn(horizon, dim) * 0.02)
        self.scalar_proj = nn.Linear(num_scalars, dim) if num_scalars else None
        self.gripper_proj = nn.Linear(1, dim)
        if self.camera_entities:
            self.camera_embed = nn.Parameter(torch.randn(len(self.camera_entities), dim) * 0.02)
            self.image_proj = nn.Linear(image_feature_dim, dim)
        self.time_embed = SinusoidalTimeEmbedding(dim)
        # The step size d of a few-step objective (flow.shortcut), added to the time embedding;
        # absent (no parameters) without one.
        self.step_size_embed = SinusoidalTimeEmbedding(dim) if step_size_conditioning else None
        self.transformer = SE3InvariantTransformer(size, depth, mlp_ratio, dropout)
        self.head = nn.Sequential(nn.LayerNorm(dim), nn.Linear(dim, 7))
        # Point-cloud group tokens (point_groups = G > 0).
        self.point_tokens = (
            PointGroupTokenizer(point_groups, point_group_size, point_width, dim) if point_groups else None
        )
        if self.point_tokens is not None:
            self.point_embed = nn.Parameter(torch.randn(dim) * 0.02)

    def encode_observations(self, obs: ObservationTokens) -> EncodedObservations:
        """Observation tokens through the transformer, once per chunk."""
        b, h_o, n = obs.p.shape[:3]
        if (h_o, n) != (self.n_obs_steps, self.num_entities):
            raise ValueError(
                f"observation poses have {h_o} history steps x {n} entities, the network expects "
                f"{self.n_obs_steps} x {self.num_entities}"
            )
        f = self.entity_embed[None, None] + self.history_embed[None, :, None]
        f = f.expand(b, h_o, n, -1)
        if self.scalar_proj is not None:
            f = f + self.scalar_proj(obs.scalars)
        r, p = obs.r, obs.p
        if self.camera_entities:
            cam = self.image_proj(obs.image_features) + self.camera_embed + self.history_embed[:, None]
            idx = list(self.camera_entities)
            f = torch.cat((f, cam), 2)
            r = torch.cat((r, r[:, :, idx]), 2)
            p = torch.cat((p, p[:, :, idx]), 2)
        l_o = f.shape[1] * f.shape[2]
        f, r, p = f.reshape(b, l_o, -1), r.reshape(b, l_o, 3, 3), p.reshape(b, l_o, 3)
        r_ref, p_ref = obs.r[:, -1, 0], obs.p[:, -1, 0]
        if self.point_tokens is not None:
            f, r, p = self._with_point_tokens(obs.points, r_ref, f, r, p)
        r_o, p_o = self.adaptation(r_ref, p_ref, r, p)
        center = p_o.mean(1, keepdim=True)
        context = self.transformer.encode_context(f, r_o, p_o - center)
        return EncodedObservations(r_ref, p_ref, center, context)

    def _with_point_tokens(
        self,
        points: torch.Tensor | None,
        r_ref: torch.Tensor,
        f: torch.Tensor,
        r: torch.Tensor,
        p: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The observation tokens ``f (B, L, C)``, ``r (B, L, 3, 3)``, ``p (B, L, 3)`` followed by
        the ``G`` point-group tokens of ``points (B, M, 3)``, posed at ``(r_ref, centre)``."""
        if points is None:
            raise ValueError(
                "the network has point-cloud tokens: ObservationTokens.points (B, M, 3) is required"
            )
        if points.ndim != 3 or points.shape[0] != f.shape[0]:
            raise ValueError(f"point cloud must have shape (B={f.shape[0]}, M, 3), got {tuple(points.shape)}")
        feats, centres = self.point_tokens(points, r_ref, self.adaptation.translation_scale)
        g = feats.shape[1]
        f = torch.cat((f, feats + self.point_embed), 1)
        r = torch.cat((r, r_ref[:, None].expand(-1, g, -1, -1)), 1)
        return f, r, torch.cat((p, centres), 1)

    def time_shifts(self, t: torch.Tensor, d: torch.Tensor | None = None) -> list[torch.Tensor]:
        """Per-block conditioning for flow times ``t (N,)`` and step sizes ``d (N,)``:
        ``depth x (N, C)``. The condition is ``E_t(t) + E_d(d)`` when the network was built with
        ``step_size_conditioning`` (``d`` None means 0, the flow-matching field), else ``E_t(t)``
        and ``d`` must be None or zeros."""
        cond = self.time_embed(t)
        if self.step_size_embed is not None:
            cond = cond + self.step_size_embed(torch.zeros_like(t) if d is None else d)
        elif d is not None and bool((d != 0).any()):
            raise ValueError(
                "this network has no step-size conditioning (few_step_objective='none'): d must be 0"
            )
        return self.transformer.time_shifts(cond)

    def velocity(
        self,
        encoded: EncodedObservations,
        x: PoseChunk,
        t: torch.Tensor | None = None,
        shifts: list[torch.Tensor] | None = None,
        d: torch.Tensor | None = None,
    ) -> PoseVelocity:
        """Local velocities of the action tokens.

        Args:
            encoded: output of :meth:`encode_observations`.
            x: current action chunk ``r (B, H, 3, 3), p (B, H, 3), g (B, H)``.
            t: flow time ``(B,)``, or instead
            shifts: its conditioning from :meth:`time_shifts` (``depth x (B or 1, C)``).
            d: step sizes ``(B,)`` with ``t`` (see :meth:`time_shifts`); ignored with ``shifts``.
        Returns:
            ``v_r (B, H, 3)``, ``v_p (B, H, 3)`` in metres, ``v_g (B, H)``.
        """
        if shifts is None:
            if t is None:
                raise ValueError("velocity needs the flow time t or its time shifts")
            shifts = self.time_shifts(t, d)
        f = self.step_embed[None] + self.gripper_proj(x.g[..., None])
        r_a, p_a = self.adaptation(encoded.r_ref, encoded.p_ref, x.r, x.p)
        out = self.transformer.forward_with_context(
            f, r_a, p_a - encoded.center, None, encoded.context, shifts=shifts
        )
        v = self.head(out)
        v_p = v[..., :3] / self.adaptation.translation_scale
        if self.translation_frame == "eef":  # v_p = r^T R_e u
            to_pose = x.r.transpose(-1, -2) @ encoded.r_ref[:, None]
            v_p = (to_pose @ v_p[..., None]).squeeze(-1)
        return PoseVelocity(r=v[..., 3:6], p=v_p, g=v[..., 6])

    def forward(self, obs: ObservationTokens, x: PoseChunk, t: torch.Tensor) -> PoseVelocity:
        """One evaluation ``v_theta``; see :meth:`velocity`."""
        return self.velocity(self.encode_observations(obs), x, t)
