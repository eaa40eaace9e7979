"""Exported samplers of ``euclidean_flow``: a checkpoint's artefacts serve its plain and guided
chunks from the first one, anything that does not match samples eagerly, and the exported
programs give the eager chunks.

As for ActionFlow, the artefact checks run by default with a stand-in package; the real
AOTInductor build is opt-in (``-m compile``)."""

import logging

import pytest
import torch

from lerobot_actionflow.policies import exported as ex
from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy
from lerobot_actionflow.policies.euclidean_flow.sampler_program import EuclideanFlowSamplerProgram
from lerobot_actionflow.policies.execution import rtc_config_of, rtc_guidance

from ..exported_stand_in import StandInRunner, used_artefact, write_stand_in
from .test_policy import ACT, ENV, STATE, _batch, _config

B, H, S = 2, 8, 2  # batch, horizon, n_obs_steps of _config


def _policy(seed=0, **kw):
    torch.manual_seed(seed)
    return EuclideanFlowPolicy(_config("unet", num_inference_steps=2, **kw)).eval()


def _observations(images=False, b=B):
    return {k: v for k, v in _batch(b=b, images=images).items() if not k.startswith("action")}


def _leftover(b=B):
    return torch.rand(b, 4, ACT, generator=torch.Generator().manual_seed(5)) * 2 - 1


@pytest.fixture
def checkpoint(tmp_path, monkeypatch):
    """A saved tiny UNet policy with stand-in plain and guided artefacts for K=2, batch 2."""
    monkeypatch.setattr(ex, "_Runner", StandInRunner)
    StandInRunner.calls = []
    policy = _policy()
    path = tmp_path / "pretrained_model"
    policy.save_pretrained(path)
    for guided in (False, True):
        write_stand_in(policy, path, k=2, guided=guided)
    return path


def test_artefacts_serve_plain_and_guided_chunks_from_the_first(checkpoint):
    policy = EuclideanFlowPolicy.from_pretrained(checkpoint)
    assert policy.exported_samplers.keys() == [ex.ArtefactKey("cpu", 2, B, g) for g in (False, True)]
    actions = policy.predict_action_chunk(_observations())
    assert used_artefact(actions) and actions.shape == (B, H - S + 1, ACT)  # from the current step
    # state, environment state, noise: the inputs the manifest names
    assert StandInRunner.calls == [[(B, S, STATE), (B, S, ENV), (B, H, ACT)]]
    guided = policy.predict_action_chunk(_observations(), inference_delay=1, prev_chunk_left_over=_leftover())
    assert used_artefact(guided)
    assert StandInRunner.calls[-1][-3:] == [(B, H, ACT), (B, H), (B, H)]

    # select_action with the default guidance: the first chunk plain, the next guided
    policy.reset()
    step = {k: v[:, 0] for k, v in _observations().items()}
    for _ in range(2 * policy.config.n_action_steps):
        policy.select_action(step)
    assert [len(c) for c in StandInRunner.calls[-2:]] == [3, 6]


def test_what_the_artefacts_do_not_serve_samples_eagerly(checkpoint, caplog):
    policy = EuclideanFlowPolicy.from_pretrained(checkpoint)
    with caplog.at_level(logging.INFO):
        assert not used_artefact(policy.predict_action_chunk(_observations(), num_inference_steps=3))
    assert "euclidean_flow: no exported sampler for K=3 batch 2 on cpu" in caplog.text
    other_grid = "uniform" if policy.config.time_spacing != "uniform" else "exponential"
    assert not used_artefact(policy.predict_action_chunk(_observations(), time_spacing=other_grid))
    assert used_artefact(
        policy.predict_action_chunk(_observations(), time_spacing=policy.config.time_spacing)
    )

    _policy(seed=1).save_pretrained(checkpoint)  # retrained: other weights
    with caplog.at_level(logging.WARNING):
        again = EuclideanFlowPolicy.from_pretrained(checkpoint)
    assert "other weights than the policy's" in caplog.text and again.exported_samplers.keys() == []
    assert not used_artefact(again.predict_action_chunk(_observations()))


@pytest.mark.parametrize("guided", [False, True], ids=["plain", "guided"])
@pytest.mark.parametrize("images", [False, True], ids=["state", "camera"])
def test_the_exported_programs_trace_to_the_eager_actions(guided, images):
    """Both programs go through ``torch.export`` (the RGB encoder too), and the traced graph gives
    ``predict_action_chunk``'s actions on the same observations, noise and leftover."""
    torch.manual_seed(0)
    policy = EuclideanFlowPolicy(_config("transformer" if images else "unet", images=images)).eval()
    program = policy.sampler_program(policy, 2, guided)
    graph = torch.export.export(
        program, program.example_inputs(B, torch.device("cpu")), strict=False
    ).module()

    batch = _observations(images)
    noise = torch.randn(B, H, ACT, generator=torch.Generator().manual_seed(4))
    obs = policy._prepare(batch, with_time=True)
    guide, rtc = (), {}
    if guided:
        g = rtc_guidance(_leftover(), 1, H, rtc_config_of(policy.config), batch_size=B, offset=S - 1)
        guide, rtc = (
            (g.target, g.weights, g.frozen),
            {"inference_delay": 1, "prev_chunk_left_over": _leftover()},
        )
    expected = policy.predict_action_chunk(batch, noise=noise, num_inference_steps=2, **rtc)
    inputs = EuclideanFlowSamplerProgram.pack(obs, noise, guide)
    assert (graph(*inputs)[:, S - 1 :] - expected).abs().max() <= 1e-5
    if guided:  # control: the same graph without the guidance's pull
        inputs[-2], inputs[-1] = torch.zeros_like(inputs[-2]), torch.zeros_like(inputs[-1])
        assert (graph(*inputs)[:, S - 1 :] - expected).abs().max() > 1e-2


@pytest.mark.compile
def test_export_command_round_trip_equals_eager(tmp_path):
    from lerobot_actionflow.export import main

    _policy().save_pretrained(tmp_path / "pretrained_model")
    # Checks exported == eager itself, to 1e-5, plain and guided.
    assert main([str(tmp_path), "--steps", "2", "--batch-sizes", "1"]) == 0
    policy = EuclideanFlowPolicy.from_pretrained(tmp_path / "pretrained_model")
    assert policy.exported_samplers.keys() == [ex.ArtefactKey("cpu", 2, 1, g) for g in (False, True)]
    assert isinstance(policy.exported_samplers._runners[("cpu", 2, 1, True)], ex._Runner)


def test_export_command_names_a_policy_type_it_cannot_export(tmp_path, capsys):
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

    from lerobot_actionflow.export import main

    config = DiffusionConfig(device="cpu", down_dims=(16, 32), n_groups=4, diffusion_step_embed_dim=16)
    config.input_features, config.output_features = _config().input_features, _config().output_features
    config.input_features = {k: v for k, v in config.input_features.items() if k != "observation.poses"}
    DiffusionPolicy(config).save_pretrained(tmp_path / "pretrained_model")
    assert main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "holds a 'diffusion' policy; actionflow-export exports 'actionflow' and 'euclidean_flow'" in err
    assert not (tmp_path / "pretrained_model" / ex.EXPORT_DIR).exists()
