"""Both policies refuse bad inputs to ``select_action`` / ``predict_action_chunk`` with a
``ValueError`` naming the feature, the expected shape and dtype, and what was given; floating
inputs of any precision are cast; a refused observation never enters the history."""

import numpy as np
import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig
from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy

from .actionflow.helpers import random_batch, small_config


def _actionflow(**kw):
    torch.manual_seed(0)
    return ActionflowPolicy(small_config(**kw)).eval()


def _euclidean(**kw):
    torch.manual_seed(0)
    config = EuclideanFlowConfig(
        device="cpu", n_layer=1, n_emb=32, horizon=8, n_action_steps=kw.pop("n_action_steps", 4),
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (11,)),
            "observation.environment_state": PolicyFeature(FeatureType.ENV, (9,)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (10,))}, **kw,
    )  # fmt: skip
    return EuclideanFlowPolicy(config).eval()


def _history(policy, batch_size=2, seed=0):
    """An observation history ``(B, n_obs_steps, ...)`` of the features ``policy`` reads."""
    gen = torch.Generator().manual_seed(seed)
    if isinstance(policy, ActionflowPolicy):
        batch = random_batch(policy.config, batch_size, gen)
    else:
        s = policy.config.n_obs_steps
        batch = {
            "observation.state": torch.randn(batch_size, s, 11, generator=gen),
            "observation.environment_state": torch.randn(batch_size, s, 9, generator=gen),
        }
    return {k: v for k, v in batch.items() if k.startswith("observation.")}


def _step(history, i=-1):
    return {k: v[:, i] for k, v in history.items()}


@pytest.fixture(scope="module", params=["actionflow", "euclidean_flow"])
def policy(request):
    return _actionflow() if request.param == "actionflow" else _euclidean()


def _first_key(policy):
    return "observation.poses" if isinstance(policy, ActionflowPolicy) else "observation.state"


def test_select_action_names_a_missing_feature(policy):
    key = _first_key(policy)
    step = _step(_history(policy))
    shape = r"\(B, 4, 7\)" if key == "observation.poses" else r"\(B, 11\)"
    del step[key]
    policy.reset()
    expected = rf"missing input feature '{key}': expected {shape}, a floating-point"
    with pytest.raises(ValueError, match=expected):
        policy.select_action(step)


@pytest.mark.parametrize("width", [22, 5])
def test_actionflow_refuses_a_state_of_the_wrong_width(width):
    policy = _actionflow()
    history = _history(policy)
    history["observation.state"] = torch.randn(2, 2, width)
    expected = (
        rf"'observation\.state' has shape \(2, 2, {width}\), dtype torch\.float32, expected \(B, 2, 11\)"
    )
    with pytest.raises(ValueError, match=expected):
        policy.predict_action_chunk(history)
    policy.reset()
    expected = rf"'observation\.state' has shape \(2, {width}\).*expected \(B, 11\)"
    with pytest.raises(ValueError, match=expected):
        policy.select_action(_step(history))


def test_floating_inputs_of_any_precision_are_cast(policy):
    history = _history(policy)

    def chunk(dtype):
        torch.manual_seed(1)
        return policy.predict_action_chunk({k: v.to(dtype) for k, v in history.items()})

    reference = chunk(torch.float32)
    assert reference.dtype == torch.float32
    torch.testing.assert_close(chunk(torch.float64), reference)
    half = chunk(torch.float16)
    assert half.dtype == torch.float32 and torch.isfinite(half).all()
    policy.reset()
    assert policy.select_action(_step({k: v.double() for k, v in history.items()})).dtype == torch.float32


def test_integer_and_numpy_inputs_are_refused_by_name(policy):
    key = _first_key(policy)
    history = _history(policy)
    given = {**history, key: history[key].round().long()}
    expected = rf"'{key}' has shape .*, dtype torch\.int64, expected .*floating-point"
    with pytest.raises(ValueError, match=expected):
        policy.predict_action_chunk(given)
    given = {**history, key: history[key].numpy().astype(np.float64)}
    expected = rf"'{key}' has type numpy\.ndarray, shape .*, dtype float64, expected"
    with pytest.raises(ValueError, match=expected):
        policy.predict_action_chunk(given)


@pytest.mark.parametrize("k", [0, -1])
def test_num_inference_steps_below_one_is_refused(policy, k):
    history = _history(policy)
    with pytest.raises(ValueError, match=rf"num_inference_steps must be an integer >= 1, got {k}"):
        policy.predict_action_chunk(history, num_inference_steps=k)


def _second_action(policy, history, bad=None):
    """The action of the step after ``history[:, 0]``, with the observation ``bad`` (refused)
    offered in between when given."""
    policy.reset()
    torch.manual_seed(2)
    policy.select_action(_step(history, 0))
    if bad is not None:
        with pytest.raises(ValueError, match=rf"'{_first_key(policy)}' contains non-finite values"):
            policy.select_action(bad)
    torch.manual_seed(3)
    return policy.select_action(_step(history, 1))


def test_a_refused_observation_leaves_the_history_unchanged():
    """n_obs_steps=2, a new chunk at every step: after a NaN observation is refused, the next
    valid one is planned from the history as if the NaN call had never happened."""
    for policy in (_actionflow(n_action_steps=1), _euclidean(n_action_steps=1)):
        history = _history(policy)
        bad = _step(history, 0)
        key = _first_key(policy)
        bad[key] = bad[key].clone()
        bad[key][0, ...] = float("nan")
        torch.testing.assert_close(_second_action(policy, history, bad), _second_action(policy, history))


def test_actionflow_images_uint8_refused_with_a_hint_any_size_accepted():
    policy = _actionflow(images=("wrist",))
    history = _history(policy)
    key = "observation.images.wrist"
    pixels = {**history, key: (history[key] * 255).to(torch.uint8)}
    expected = rf"'{key}' has shape \(2, 2, 3, 32, 32\), dtype torch\.uint8, expected \(B, 2, 3, H, W\)"
    with pytest.raises(ValueError, match=expected + r".*run the policy's preprocessor"):
        policy.predict_action_chunk(pixels)
    larger = {**history, key: torch.rand(2, 2, 3, 40, 48)}  # the encoder resizes to image_size
    assert policy.predict_action_chunk(larger).shape == (2, 8, 10)
