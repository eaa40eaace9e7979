"""The processor step from a robot's flat observation to the dataset's features.

A LeRobot robot reports scalars, so ``lerobot-rollout`` hands a policy one flat
``observation.state`` of width ``16 N + 2`` (:mod:`lerobot_actionflow.robots.layout`); the
policies were trained on the dataset's ``observation.state (11)``,
``observation.environment_state (9 (N - 1))`` and ``observation.poses (N, 7)``.
:class:`RobotObservationToPolicyStep` (registry name ``actionflow_robot_observation``) splits
the former into the latter inside the policy's preprocessor, before normalisation. A batch that
already holds the dataset's features (``observation.poses``, or an ``observation.state`` of the
dataset's width: a training batch, ``lerobot-eval``'s env) passes unchanged, so the step can sit
in every preprocessor of a policy trained on our datasets.

:func:`add_robot_observation_step` inserts the step into a saved checkpoint's preprocessor
(command line: :mod:`lerobot_actionflow.robots.prepare_checkpoint`), for checkpoints whose
preprocessor does not have it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature, PreTrainedConfig
from lerobot.processor import ObservationProcessorStep, PolicyProcessorPipeline, ProcessorStepRegistry
from lerobot.processor.converters import batch_to_transition, transition_to_batch

from lerobot_actionflow.robots.layout import flat_width, split_flat_observation
from lerobot_actionflow.schema import (
    ENV_STATE_KEY,
    POSE9_DIM,
    POSES_KEY,
    STATE_DIM,
    STATE_KEY,
    feature_shapes,
)

REGISTRY_NAME = "actionflow_robot_observation"
PREPROCESSOR_FILE = "policy_preprocessor.json"
_TYPES = {STATE_KEY: FeatureType.STATE, ENV_STATE_KEY: FeatureType.ENV, POSES_KEY: FeatureType.STATE}


@ProcessorStepRegistry.register(name=REGISTRY_NAME)
@dataclass
class RobotObservationToPolicyStep(ObservationProcessorStep):
    """Split a flat robot ``observation.state (..., 16 N + 2)`` into the dataset's features.

    Attributes:
        num_tokens: N, the task's pose tokens (end-effector included).
    """

    num_tokens: int = 2

    def __post_init__(self):
        if int(self.num_tokens) < 1:
            raise ValueError(f"num_tokens must be >= 1, got {self.num_tokens}")

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        state = observation.get(STATE_KEY)
        if POSES_KEY in observation or (state is not None and state.shape[-1] == STATE_DIM):
            return observation  # the dataset's features already (training, lerobot-eval)
        if state is None:
            raise ValueError(f"observation has neither '{POSES_KEY}' nor a flat robot '{STATE_KEY}'")
        observation.update(split_flat_observation(state, self.num_tokens))
        return observation

    def get_config(self) -> dict[str, Any]:
        return {"num_tokens": self.num_tokens}

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        obs = features.get(PipelineFeatureType.OBSERVATION, {})
        state = obs.get(STATE_KEY)
        if POSES_KEY in obs or state is None or tuple(state.shape) != (flat_width(self.num_tokens),):
            return features
        shapes = feature_shapes(self.num_tokens)
        new_obs = {k: v for k, v in obs.items() if k != STATE_KEY}
        new_obs.update({k: PolicyFeature(type=t, shape=shapes[k]) for k, t in _TYPES.items()})
        return {**features, PipelineFeatureType.OBSERVATION: new_obs}


def num_tokens_of(config: PreTrainedConfig) -> int:
    """N from a policy's input features (``observation.poses`` or the environment state)."""
    feats = config.input_features
    if POSES_KEY in feats:
        return int(feats[POSES_KEY].shape[0])
    if ENV_STATE_KEY in feats:
        return int(feats[ENV_STATE_KEY].shape[0]) // POSE9_DIM + 1
    raise ValueError(f"policy has neither '{POSES_KEY}' nor '{ENV_STATE_KEY}' in its inputs: {list(feats)}")


def robot_observation_steps(config: PreTrainedConfig) -> list[RobotObservationToPolicyStep]:
    """The splitting step for a policy's preprocessor, or none when the policy reads neither
    pose tokens nor object poses (a robot's flat observation would not fit it anyway)."""
    feats = config.input_features
    if POSES_KEY not in feats and ENV_STATE_KEY not in feats:
        return []
    return [RobotObservationToPolicyStep(num_tokens=num_tokens_of(config))]


def add_robot_observation_step(pretrained_path: str | Path) -> bool:
    """Insert :class:`RobotObservationToPolicyStep` into the checkpoint's preprocessor, after
    its renaming step and before everything else; returns False if it was there already."""
    path = Path(pretrained_path)
    config = PreTrainedConfig.from_pretrained(path)
    pipeline = PolicyProcessorPipeline.from_pretrained(
        path,
        config_filename=PREPROCESSOR_FILE,
        to_transition=batch_to_transition,
        to_output=transition_to_batch,
    )
    if any(isinstance(s, RobotObservationToPolicyStep) for s in pipeline.steps):
        return False
    n = num_tokens_of(config)
    at = next((i + 1 for i, s in enumerate(pipeline.steps) if s.__class__.__name__.startswith("Rename")), 0)
    pipeline.steps.insert(at, RobotObservationToPolicyStep(num_tokens=n))
    pipeline.save_pretrained(path)
    return True
