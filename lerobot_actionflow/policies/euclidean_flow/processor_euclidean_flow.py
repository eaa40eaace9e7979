"""Pre/post-processors of ``euclidean_flow``: LeRobot's standard pipelines.

Pre: rename -> split a robot's flat observation into the dataset's features (``lerobot-rollout``;
:mod:`lerobot_actionflow.robots.processor`) -> add batch dim -> device -> normalise (state,
environment state and actions min-max to ``[-1, 1]``, images mean/std). Post: unnormalise
actions -> CPU. The point cloud (``point_cloud_key``) is not normalised (metres); with
``wrist_focus_camera`` set, :class:`~lerobot_actionflow.policies.wrist_focus.WristFocusStep` masks
that camera's image before normalisation (App. G.3).

Only the features the policy reads are normalised: other observation keys (for example
``observation.poses``, which is typed STATE by LeRobot) pass through untouched, explicitly
rather than by luck of the stats.
"""

from __future__ import annotations

from typing import Any

import torch
from lerobot.processor import PolicyAction, PolicyProcessorPipeline
from lerobot.processor.factory import make_default_policy_processor_steps, make_policy_processor_pipelines
from lerobot.processor.normalize_processor import NormalizerProcessorStep

from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig
from lerobot_actionflow.policies.wrist_focus import wrist_focus_steps
from lerobot_actionflow.robots.processor import robot_observation_steps


def make_euclidean_flow_pre_post_processors(
    config: EuclideanFlowConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """``(preprocessor, postprocessor)`` for ``config``, normalising with ``dataset_stats``."""
    s = make_default_policy_processor_steps(config, dataset_stats)
    # The point cloud stays in metres: per-element statistics of an FPS-ordered cloud mean nothing.
    used = {k: ft for k, ft in config.used_input_features.items() if k != config.point_cloud_key}
    normalize = NormalizerProcessorStep(
        features={**used, **config.output_features},
        norm_map=config.normalization_mapping,
        stats=dataset_stats,
    )
    # A robot's flat observation (lerobot-rollout) back into the dataset's features.
    return make_policy_processor_pipelines(
        input_steps=[
            s.rename_observations,
            *robot_observation_steps(config),
            s.add_batch_dim,
            s.to_device,
            *wrist_focus_steps(config),
            normalize,
        ],
        output_steps=[s.unnormalize, s.to_cpu],
    )
