"""Both policies share their chunk conventions: ``predict_action_chunk`` returns the actions from
the current step on, and ``select_action`` executes the first ``n_action_steps`` of that chunk."""

from __future__ import annotations

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow.flow import se3 as se3_flow
from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig
from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy
from lerobot_actionflow.schema import ACTION_DIM, ACTION_KEY, ENV_STATE_KEY, STATE_DIM, STATE_KEY

from .actionflow.helpers import random_batch, small_config

HORIZON, N_OBS, N_ACTION = 8, 2, 3


def _actionflow():
    from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy

    torch.manual_seed(0)
    policy = ActionflowPolicy(small_config(horizon=HORIZON, n_obs_steps=N_OBS, n_action_steps=N_ACTION))
    batch = random_batch(policy.config, 2, torch.Generator().manual_seed(1))
    noise = se3_flow.draw_local_noise(2, HORIZON, 0.1, generator=torch.Generator().manual_seed(2))
    return policy.eval(), batch, noise, HORIZON


def _euclidean_flow():
    torch.manual_seed(0)
    cfg = EuclideanFlowConfig(
        device="cpu", n_layer=1, n_emb=32, horizon=HORIZON, n_obs_steps=N_OBS, n_action_steps=N_ACTION,
        input_features={
            STATE_KEY: PolicyFeature(FeatureType.STATE, (STATE_DIM,)),
            ENV_STATE_KEY: PolicyFeature(FeatureType.ENV, (9,)),
        },
        output_features={ACTION_KEY: PolicyFeature(FeatureType.ACTION, (ACTION_DIM,))},
    )  # fmt: skip
    gen = torch.Generator().manual_seed(1)
    batch = {
        STATE_KEY: torch.randn(2, N_OBS, STATE_DIM, generator=gen),
        ENV_STATE_KEY: torch.randn(2, N_OBS, 9, generator=gen),
    }
    noise = torch.randn(2, HORIZON, ACTION_DIM, generator=torch.Generator().manual_seed(2))
    return EuclideanFlowPolicy(cfg).eval(), batch, noise, HORIZON - N_OBS + 1


@pytest.mark.parametrize("make", [_actionflow, _euclidean_flow], ids=["actionflow", "euclidean_flow"])
def test_select_action_executes_the_chunk_from_the_current_step(make):
    policy, batch, noise, from_current_step = make()
    # select_action's history starts as the first observation repeated: give the chunk the same
    history = {
        k: v[:, :1].expand(-1, N_OBS, *v.shape[2:]).clone() for k, v in batch.items() if k != ACTION_KEY
    }
    chunk = policy.predict_action_chunk(history, noise=noise)
    assert chunk.shape == (2, from_current_step, ACTION_DIM)
    policy.reset()
    step = {k: v[:, 0] for k, v in history.items()}
    executed = torch.stack([policy.select_action(step, noise=noise) for _ in range(N_ACTION)], 1)
    torch.testing.assert_close(executed, chunk[:, :N_ACTION])
    # control: the next call plans a new chunk from the queue, not the rest of this one
    assert len(policy._queues[ACTION_KEY]) == 0
