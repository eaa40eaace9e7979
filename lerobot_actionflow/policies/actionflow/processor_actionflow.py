"""Pre/post-processing pipelines of the ActionFlow policy.

Pre: rename -> split a robot's flat observation into the dataset's features (``lerobot-rollout``;
:mod:`lerobot_actionflow.robots.processor`) -> add batch dim -> device -> normalise.
Normalisation is restricted, per feature, to what may be normalised: ``observation.poses`` and
``action`` are passed through untouched whatever ``normalization_mapping`` says, because
mean/std scaling of positions would break SE(3) equivariance (the network's adaptation module
handles scale); so is the point cloud the config reads (metres, like the poses). With
``wrist_focus_camera`` set, :class:`~lerobot_actionflow.policies.wrist_focus.WristFocusStep`
masks that camera's image before normalisation (App. G.3). Post: to CPU (actions are absolute poses already).
"""

from __future__ import annotations

from typing import Any

import torch
from lerobot.processor import PolicyAction, PolicyProcessorPipeline
from lerobot.processor.factory import make_default_policy_processor_steps, make_policy_processor_pipelines
from lerobot.processor.normalize_processor import NormalizerProcessorStep, UnnormalizerProcessorStep

from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig
from lerobot_actionflow.policies.wrist_focus import wrist_focus_steps
from lerobot_actionflow.robots.processor import robot_observation_steps
from lerobot_actionflow.schema import ACTION_KEY, POSES_KEY

#: Features never normalised: they are poses.
POSE_FEATURES = (POSES_KEY, ACTION_KEY)


def make_actionflow_pre_post_processors(
    config: ActionflowConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    steps = make_default_policy_processor_steps(config, dataset_stats)
    raw = (*POSE_FEATURES, config.point_cloud_key)
    normalize = NormalizerProcessorStep(
        features={k: ft for k, ft in config.input_features.items() if k not in raw},
        norm_map=config.normalization_mapping,
        stats=dataset_stats,
    )
    # Kept (as a pass-through for the pose action) so that the pipeline has the step LeRobot
    # addresses by name when it reloads processors, e.g. on --resume.
    unnormalize = UnnormalizerProcessorStep(
        features={k: ft for k, ft in config.output_features.items() if k not in POSE_FEATURES},
        norm_map=config.normalization_mapping,
        stats=dataset_stats,
    )
    # A robot's flat observation (lerobot-rollout) back into the dataset's features.
    return make_policy_processor_pipelines(
        input_steps=[
            steps.rename_observations,
            *robot_observation_steps(config),
            steps.add_batch_dim,
            steps.to_device,
            *wrist_focus_steps(config),
            normalize,
        ],
        output_steps=[unnormalize, steps.to_cpu],
    )
