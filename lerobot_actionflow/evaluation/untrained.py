"""A tiny untrained ActionFlow checkpoint for a task: what smoke tests of evaluation and
deployment pipelines load (``lerobot-eval --policy.path=...``) when the policy's skill does not
matter, only that every stage runs."""

from __future__ import annotations

from pathlib import Path

import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow.envs.tasks import get_task
from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig
from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
from lerobot_actionflow.policies.actionflow.processor_actionflow import make_actionflow_pre_post_processors
from lerobot_actionflow.schema import ACTION_KEY, POSES_KEY, STATE_KEY, feature_shapes


def save_untrained_actionflow(task: str, path: Path, seed: int = 0) -> Path:
    """Save a 1-layer, width-16 ActionFlow for ``task``'s pose tokens (horizon 8, 4 actions per
    chunk), initialised with ``seed``, and its pre/post processors, to ``path``; returns ``path``."""
    shapes = feature_shapes(get_task(task).num_tokens)
    cfg = ActionflowConfig(
        input_features={
            POSES_KEY: PolicyFeature(FeatureType.STATE, shapes[POSES_KEY]),
            STATE_KEY: PolicyFeature(FeatureType.STATE, shapes[STATE_KEY]),
        },
        output_features={ACTION_KEY: PolicyFeature(FeatureType.ACTION, shapes[ACTION_KEY])},
        dim=16, num_layers=1, num_heads=2, head_dim=4, num_query_points=2, num_value_points=2,
        horizon=8, n_action_steps=4, device="cpu", push_to_hub=False,
    )  # fmt: skip
    torch.manual_seed(seed)
    ActionflowPolicy(cfg).save_pretrained(path)
    pre, post = make_actionflow_pre_post_processors(cfg)
    pre.save_pretrained(path)
    post.save_pretrained(path)
    return path
