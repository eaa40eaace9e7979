"""``euclidean_flow``'s sampler as one exportable program (:mod:`lerobot_actionflow.policies.exported`).

Inputs, in order: the prepared observation history the policy reads, among
``observation.state (B, S, d_s)``, ``observation.images (B, S, N, C, H, W)`` (the cameras
stacked) and ``observation.environment_state (B, S, d_e)``, then the initial noise
``a_0 (B, H, A)``, then for the guided program the known actions ``target (B, H, A)``,
``weights (B, H)`` and ``frozen (B, H)``. Output: the normalised chunk ``(B, H, A)``. The
observation encoder (the RGB encoders too) is part of the program.
"""

from __future__ import annotations

import torch
from lerobot.utils.constants import OBS_ENV_STATE, OBS_IMAGES, OBS_STATE
from torch import Tensor, nn

from lerobot_actionflow.flow.schedules import make_time_grid

#: The observation inputs, in the program's order (each only when the policy reads it).
OBSERVATION_ORDER = (OBS_STATE, OBS_IMAGES, OBS_ENV_STATE)


class EuclideanFlowSamplerProgram(nn.Module):
    """:meth:`EuclideanFlowPolicy.sample_from_observations` (or, guided,
    :meth:`EuclideanFlowPolicy.guided_sample_from_observations`) with K's flow times on the
    config's grid as a constant (module docstring)."""

    def __init__(self, policy, num_inference_steps: int, guided: bool = False):
        super().__init__()
        cfg = policy.config
        self.policy = policy
        self.guided = guided
        self.observation_keys = observation_keys(cfg)
        self.register_buffer(
            "times",
            make_time_grid(num_inference_steps, cfg.time_spacing, rate=cfg.time_spacing_rate),
            persistent=False,
        )

    def input_names(self) -> tuple[str, ...]:
        return (*self.observation_keys, "noise", *(("target", "weights", "frozen") if self.guided else ()))

    @staticmethod
    def pack(obs: dict[str, Tensor], noise: Tensor, guide: tuple[Tensor, ...] = ()) -> list[Tensor]:
        """The program's inputs in order, from a prepared history (``guide``: target, weights,
        frozen for the guided program)."""
        return [*(obs[k] for k in OBSERVATION_ORDER if k in obs), noise, *guide]

    def forward(self, *inputs: Tensor) -> Tensor:
        n = len(self.observation_keys)
        obs = dict(zip(self.observation_keys, inputs[:n], strict=True))
        noise = inputs[n]
        times = self.times.to(noise.dtype)
        if not self.guided:
            return self.policy.sample_from_observations(obs, noise, times)
        target, weights, frozen = inputs[n + 1 :]
        return self.policy.guided_sample_from_observations(obs, noise, times, target, weights, frozen)

    def example_inputs(self, batch_size: int, device: torch.device) -> tuple[Tensor, ...]:
        """Inputs of the program's shapes (zeros; the values do not matter)."""
        cfg = self.policy.config
        s, h, a = cfg.n_obs_steps, cfg.horizon, cfg.action_feature.shape[0]
        shapes = {OBS_STATE: lambda: tuple(cfg.robot_state_feature.shape)}
        shapes[OBS_ENV_STATE] = lambda: tuple(cfg.env_state_feature.shape)
        shapes[OBS_IMAGES] = lambda: (len(cfg.image_features), *next(iter(cfg.image_features.values())).shape)
        obs = {k: torch.zeros(batch_size, s, *shapes[k](), device=device) for k in self.observation_keys}
        guide = ()
        if self.guided:  # every input its own tensor: torch.export treats a repeated one as one input
            zeros = torch.zeros(batch_size, h, device=device)
            guide = (torch.zeros(batch_size, h, a, device=device), zeros, zeros.bool())
        return tuple(self.pack(obs, torch.zeros(batch_size, h, a, device=device), guide))


def observation_keys(cfg) -> tuple[str, ...]:
    """The prepared observation keys a ``euclidean_flow`` config reads, in the program's order."""
    read = {
        OBS_STATE: cfg.robot_state_feature is not None,
        OBS_IMAGES: bool(cfg.image_features),
        OBS_ENV_STATE: cfg.read_env_state_feature is not None,
    }
    return tuple(k for k in OBSERVATION_ORDER if read[k])
