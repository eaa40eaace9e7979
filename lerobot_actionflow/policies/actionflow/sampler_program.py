"""ActionFlow's sampler as one exportable program (:mod:`lerobot_actionflow.policies.exported`).

Inputs, in order: ``observation.poses (B, S, N, 7)``, then ``observation.state (B, S, 11)`` and
the image features ``(B, S, N_cam, 512)`` when the policy reads them, then the initial noise in
the EEF frame ``noise_r (B, H, 3, 3)``, ``noise_p (B, H, 3)``, ``noise_g (B, H)``, then for the
guided program the known actions ``target (B, H, 10)``, ``weights (B, H)`` and ``frozen (B, H)``.
Output: the actions ``(B, H, 10)``.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lerobot_actionflow.flow import schedules
from lerobot_actionflow.flow.se3 import LocalNoise
from lerobot_actionflow.nn.image_encoder import ResNet18Encoder
from lerobot_actionflow.schema import POSES_KEY, STATE_DIM, STATE_KEY
from lerobot_actionflow.schema.tensors import pose_to_action


class ActionflowSamplerProgram(nn.Module):
    """:meth:`ActionflowPolicy.sample_from_observations` (or, guided,
    :meth:`ActionflowPolicy.guided_sample_from_observations`) with K's flow times as a constant,
    taking only the tensors the policy reads (module docstring)."""

    def __init__(self, policy, num_inference_steps: int, guided: bool = False):
        super().__init__()
        cfg = policy.config
        self.policy = policy
        self.guided = guided
        self.has_state = bool(cfg.num_scalars)
        self.has_images = bool(policy.image_keys)
        self.register_buffer(
            "times",
            schedules.make_time_grid(
                num_inference_steps, cfg.time_spacing, cfg.time_spacing_rate, torch.float32, "cpu"
            ),
            persistent=False,
        )

    def input_names(self) -> tuple[str, ...]:
        names = [POSES_KEY]
        if self.has_state:
            names.append(STATE_KEY)
        if self.has_images:
            names.append("image_features")
        names += ["noise_r", "noise_p", "noise_g"]
        if self.guided:
            names += ["target", "weights", "frozen"]
        return tuple(names)

    @staticmethod
    def pack(
        poses: Tensor,
        state: Tensor | None,
        image_features: Tensor | None,
        noise: LocalNoise,
        guide: tuple[Tensor, Tensor, Tensor] | None = None,
    ) -> list[Tensor]:
        """The program's inputs in order (``state`` / ``image_features`` None when not read;
        ``guide``: target, weights, frozen for the guided program)."""
        observed = [t for t in (poses, state, image_features) if t is not None]
        return [*observed, noise.r, noise.p, noise.g, *(guide or ())]

    def forward(self, *inputs: Tensor) -> Tensor:
        it = iter(inputs)
        poses = next(it)
        state = next(it) if self.has_state else None
        image_features = next(it) if self.has_images else None
        noise = next(it), next(it), next(it)
        times = self.times.to(poses.dtype)
        if not self.guided:
            return self.policy.sample_from_observations(poses, state, image_features, *noise, times)
        target, weights, frozen = it
        return self.policy.guided_sample_from_observations(
            poses, state, image_features, *noise, times, target, weights, frozen, frozen_path=True
        )

    def example_inputs(self, batch_size: int, device: torch.device) -> tuple[Tensor, ...]:
        """Valid inputs of the program's shapes (identity rotations; the values do not matter)."""
        cfg, policy = self.policy.config, self.policy
        s, n, h = cfg.n_obs_steps, policy.num_entities, cfg.horizon
        poses = torch.zeros(batch_size, s, n, 7, device=device)
        poses[..., 6] = 1.0
        state = torch.zeros(batch_size, s, STATE_DIM, device=device) if self.has_state else None
        image_features = (
            torch.zeros(batch_size, s, len(policy.image_keys), ResNet18Encoder.out_dim, device=device)
            if self.has_images
            else None
        )

        # Every input its own tensor: torch.export treats one tensor passed twice as one input.
        def eye() -> Tensor:
            return torch.eye(3, device=device).expand(batch_size, h, 3, 3).contiguous()

        def zeros(*shape: int, dtype=torch.float32) -> Tensor:
            return torch.zeros(batch_size, h, *shape, device=device, dtype=dtype)

        noise = LocalNoise(eye(), zeros(3), zeros())
        guide = (pose_to_action(eye(), zeros(3), zeros()), zeros(), zeros(dtype=torch.bool))
        return tuple(self.pack(poses, state, image_features, noise, guide if self.guided else None))
