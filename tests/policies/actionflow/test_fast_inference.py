"""The fast-inference option (compiled K-step samplers, plain and guided) returns the eager
samplers' actions."""

import pytest
import torch

from lerobot_actionflow.flow import se3 as se3_flow
from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy

from .helpers import random_batch, small_config


def _eager_and_compiled():
    """Two policies with the same weights: one eager, one with ``compile_sampler``."""
    torch.manual_seed(0)
    eager = ActionflowPolicy(small_config(compile_sampler=False, compile_mode="default")).eval()
    fast = ActionflowPolicy(small_config(compile_sampler=True, compile_mode="default")).eval()
    fast.load_state_dict(eager.state_dict())
    return eager, fast


@pytest.mark.compile
def test_compiled_sampler_matches_eager():
    eager, fast = _eager_and_compiled()
    gen = torch.Generator().manual_seed(1)
    batch = random_batch(eager.config, 2, gen)
    noise = se3_flow.draw_local_noise(2, eager.config.horizon, 0.1, generator=gen)
    a_eager = eager.predict_action_chunk(batch, noise=noise, num_inference_steps=2)
    a_fast = fast.predict_action_chunk(batch, noise=noise, num_inference_steps=2)
    assert list(fast._compiled_samplers) == [False] and not eager._compiled_samplers
    assert torch.allclose(a_eager, a_fast, atol=1e-4)
    # The output is a fresh tensor, not a buffer a later call would overwrite.
    a_again = fast.predict_action_chunk(
        random_batch(eager.config, 2, gen), noise=noise, num_inference_steps=2
    )
    assert not torch.allclose(a_fast, a_again)
    assert torch.allclose(
        a_fast, eager.predict_action_chunk(batch, noise=noise, num_inference_steps=2), atol=1e-4
    )
    # New weights reach the compiled sampler (on the CPU it folds them in as constants).
    with torch.no_grad():
        for p in eager.parameters():
            p.add_(0.05 * torch.randn_like(p))
    fast.load_state_dict(eager.state_dict())
    a_new = eager.predict_action_chunk(batch, noise=noise, num_inference_steps=2)
    assert not torch.allclose(a_new, a_eager, atol=1e-3)
    assert torch.allclose(
        a_new, fast.predict_action_chunk(batch, noise=noise, num_inference_steps=2), atol=1e-4
    )


@pytest.mark.compile
def test_compiled_guided_sampler_matches_eager():
    """Guided chunks (``guide_to_previous_chunk``, RTC) through the compiled guided sampler."""
    eager, fast = _eager_and_compiled()
    gen = torch.Generator().manual_seed(1)
    batch = random_batch(eager.config, 2, gen)
    leftover = batch.pop("action")[:, 3:]
    noise = se3_flow.draw_local_noise(2, eager.config.horizon, 0.1, generator=gen)
    for delay in (0, 2):  # nothing frozen, and a frozen prefix: one graph serves both
        kw = dict(noise=noise, num_inference_steps=2, inference_delay=delay, prev_chunk_left_over=leftover)
        a_eager = eager.predict_action_chunk(batch, **kw)
        a_fast = fast.predict_action_chunk(batch, **kw)
        assert torch.allclose(a_eager, a_fast, atol=1e-4)
        torch.testing.assert_close(a_fast[:, :delay], leftover[:, :delay], rtol=0, atol=0)
    assert list(fast._compiled_samplers) == [True] and not eager._compiled_samplers
    # control: the plain chunk of the same noise is another chunk
    assert not torch.allclose(a_fast, fast.predict_action_chunk(batch, noise=noise, num_inference_steps=2))


def test_compile_is_automatic_on_cuda_only():
    policy = ActionflowPolicy(small_config())
    assert policy.config.compile_sampler is None
    assert policy._use_compiled_sampler(torch.device("cuda"))
    assert not policy._use_compiled_sampler(torch.device("cpu"))


def test_compiled_sampler_is_dropped_when_weights_may_change():
    # The CPU sampler is compiled with frozen weights: training or loading weights must recompile.
    policy = ActionflowPolicy(small_config(compile_sampler=True)).eval()
    compiled = {False: object(), True: object()}  # the plain and the guided sampler
    policy._compiled_samplers.update(compiled)
    policy.eval()
    assert policy._compiled_samplers == compiled
    policy.train()
    assert not policy._compiled_samplers
    policy.eval()._compiled_samplers.update(compiled)
    policy.load_state_dict(policy.state_dict())
    assert not policy._compiled_samplers


def test_inference_step_sweep_sets_actionflow_euler_steps():
    from lerobot_actionflow.evaluation.sweep import set_inference_steps

    policy = ActionflowPolicy(small_config()).eval()
    calls = []
    original = policy.network.velocity
    policy.network.velocity = lambda *a, **k: calls.append(1) or original(*a, **k)
    assert set_inference_steps(policy, 3, "exponential") == "euler-exponential-guided"  # the default
    policy.predict_action_chunk(random_batch(policy.config, 1, torch.Generator().manual_seed(0)))
    assert len(calls) == 3
