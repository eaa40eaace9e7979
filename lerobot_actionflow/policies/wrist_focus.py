"""The image trick of App. G.3: once the gripper is closed, the wrist camera sees only its centre.

Paper: "once the robot's gripper is closed, we set all pixels to black apart from the image's
center region of size 30x30 pixels". Here, per batch element and observation step:

    closed = |q_1 - q_2| < threshold,   q = observation.state[..., STATE_GRIPPER_INDICES]
    image[..., c, v, u] = 0 unless v, u lie in the central size x size square, when closed

(``q`` the two finger joint positions in metres, so ``|q_1 - q_2|`` is the finger opening;
0 is black for images in ``[0, 1]``, i.e. before normalisation). Images smaller than the square
are left whole. :class:`WristFocusStep` (registry name ``actionflow_wrist_focus``) does this in
a policy's preprocessor, before normalisation, so training batches, ``lerobot-eval`` and
``lerobot-rollout`` see the same masked images; both policies add it when their config names
``wrist_focus_camera``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from lerobot.configs import PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry

from lerobot_actionflow.policies.config_errors import require, require_ints, require_positive
from lerobot_actionflow.schema import IMAGES_PREFIX, STATE_GRIPPER_INDICES, STATE_KEY

REGISTRY_NAME = "actionflow_wrist_focus"
#: Finger opening (metres) below which the gripper counts as closed: a Panda hand holding the
#: MugHang handle (0.012 m thick) reads about 0.012; fully open, 0.08.
WRIST_FOCUS_THRESHOLD = 0.02


def gripper_opening(state: torch.Tensor) -> torch.Tensor:
    """Finger opening ``(...)`` in metres from ``observation.state (..., 11)``."""
    q = state[..., list(STATE_GRIPPER_INDICES)]
    return (q[..., 0] - q[..., 1]).abs()


def focus_mask(image: torch.Tensor, closed: torch.Tensor, size: int) -> torch.Tensor:
    """``image (..., C, H, W)`` with every pixel outside the central ``size x size`` square set
    to 0 where ``closed (...)`` is true (the leading dimensions of both agree)."""
    h, w = image.shape[-2:]
    keep = torch.zeros(h, w, dtype=torch.bool, device=image.device)
    top, left = max((h - size) // 2, 0), max((w - size) // 2, 0)
    keep[top : top + size, left : left + size] = True
    black = closed.to(image.device)[..., None, None, None] & ~keep
    return image.masked_fill(black, 0)


@ProcessorStepRegistry.register(name=REGISTRY_NAME)
@dataclass
class WristFocusStep(ObservationProcessorStep):
    """Mask ``camera``'s image outside its centre while the gripper is closed (module docstring).

    Attributes:
        camera: the image feature key, e.g. ``observation.images.wrist``.
        size: side of the kept central square, in pixels.
        threshold: finger opening (metres) below which the gripper is closed.
    """

    camera: str = IMAGES_PREFIX + "wrist"
    size: int = 30
    threshold: float = WRIST_FOCUS_THRESHOLD

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        if self.camera not in observation:
            raise ValueError(
                f"wrist focus: the observation has no image '{self.camera}' ({sorted(observation)})"
            )
        if STATE_KEY not in observation:
            raise ValueError(
                f"wrist focus needs '{STATE_KEY}' for the gripper opening ({sorted(observation)})"
            )
        image, state = observation[self.camera], observation[STATE_KEY]
        closed = gripper_opening(torch.as_tensor(state)) < self.threshold
        if tuple(closed.shape) != tuple(image.shape[:-3]):
            raise ValueError(
                f"wrist focus: '{self.camera}' of shape {tuple(image.shape)} and '{STATE_KEY}' of shape "
                f"{tuple(state.shape)} have different leading (batch, time) dimensions"
            )
        observation = dict(observation)
        observation[self.camera] = focus_mask(image, closed, self.size)
        return observation

    def get_config(self) -> dict[str, Any]:
        return {"camera": self.camera, "size": self.size, "threshold": self.threshold}

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        return features


def validate_wrist_focus_fields(config: Any) -> None:
    """``wrist_focus_camera`` is None or an image key; size >= 1; threshold > 0."""
    cam = config.wrist_focus_camera
    require(
        cam is None or (isinstance(cam, str) and cam.startswith(IMAGES_PREFIX)),
        f"`wrist_focus_camera` must be None or an image key '{IMAGES_PREFIX}<camera>', got {cam!r}",
    )
    require_ints(config, ("wrist_focus_size",))
    require_positive(config, ("wrist_focus_threshold",))


def check_wrist_focus_features(config: Any) -> None:
    """The named camera is an image input, and ``observation.state`` (the gripper) is an input."""
    cam = config.wrist_focus_camera
    if cam is None:
        return
    feats = config.input_features or {}
    if cam not in config.image_features:
        raise ValueError(f"wrist_focus_camera '{cam}' is not an image input feature ({sorted(feats)})")
    if STATE_KEY not in feats:
        raise ValueError(f"wrist_focus_camera needs '{STATE_KEY}' (the gripper opening) among the inputs")


def wrist_focus_steps(config: Any) -> list[WristFocusStep]:
    """The step for a policy's preprocessor, or none when ``wrist_focus_camera`` is None."""
    if config.wrist_focus_camera is None:
        return []
    return [
        WristFocusStep(
            camera=config.wrist_focus_camera,
            size=config.wrist_focus_size,
            threshold=config.wrist_focus_threshold,
        )
    ]
