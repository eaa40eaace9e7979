"""Exported samplers: which artefact a checkpoint may use, for plain and guided chunks, and that a
real one gives the eager actions.

The refusal logic runs by default with a stand-in for the compiled package (the manifest checks
never load it); the real export (AOTInductor, minutes on a 2-core CPU) is opt-in: ``-m compile``.
"""

import logging
import shutil

import pytest
import torch

from lerobot_actionflow.flow import se3 as se3_flow
from lerobot_actionflow.policies import exported as ex
from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
from lerobot_actionflow.schema.tensors import action_to_pose

from ..exported_stand_in import StandInRunner, used_artefact, write_stand_in
from .helpers import random_batch, small_config, transform_batch
from .test_equivariance import _equivariance_error, _random_transform, _sample_twice


@pytest.fixture
def checkpoint(tmp_path, monkeypatch):
    """A saved tiny policy with a stand-in artefact for K=2, batch 2 on the CPU that matches it."""
    monkeypatch.setattr(ex, "_Runner", StandInRunner)
    StandInRunner.calls = []
    torch.manual_seed(0)
    policy = ActionflowPolicy(small_config()).eval()
    path = tmp_path / "pretrained_model"
    policy.save_pretrained(path)
    write_stand_in(policy, path, k=2)
    return path


PLAIN_K2 = ex.ArtefactKey("cpu", 2, 2)
GUIDED_K2 = ex.ArtefactKey("cpu", 2, 2, guided=True)


def chunk(policy, k=2, batch_size=2):
    return policy.predict_action_chunk(
        random_batch(policy.config, batch_size, torch.Generator().manual_seed(1)), num_inference_steps=k
    )


def test_a_matching_artefact_is_used_from_the_first_chunk(checkpoint):
    policy = ActionflowPolicy.from_pretrained(checkpoint)
    assert policy.exported_samplers.keys() == [PLAIN_K2]
    assert used_artefact(chunk(policy))
    # poses, state, noise r / p / g: the inputs the manifest names, batch first.
    assert StandInRunner.calls == [[(2, 2, 4, 7), (2, 2, 11), (2, 8, 3, 3), (2, 8, 3), (2, 8)]]


def test_other_k_samples_eagerly_and_says_so(checkpoint, caplog):
    policy = ActionflowPolicy.from_pretrained(checkpoint)
    with caplog.at_level(logging.INFO):
        actions = chunk(policy, k=3)
    assert not used_artefact(actions)
    assert "no exported sampler for K=3 batch 2 on cpu (exported: K=2 batch 2 on cpu); sampling eagerly" in (
        caplog.text
    )


def test_other_batch_size_samples_eagerly_and_says_so(checkpoint, caplog):
    policy = ActionflowPolicy.from_pretrained(checkpoint)
    with caplog.at_level(logging.INFO):
        assert not used_artefact(chunk(policy, batch_size=1))
    assert "no exported sampler for K=2 batch 1 on cpu" in caplog.text
    assert used_artefact(chunk(policy, batch_size=2))


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        (lambda policy, path: write_stand_in(policy, path, 2, weights_sha256="0" * 64), "other weights"),
        (lambda policy, path: write_stand_in(policy, path, 2, config_sha256="0" * 64), "other configuration"),
        (lambda policy, path: write_stand_in(policy, path, 2, torch="1.0"), "torch version '1.0'"),
        (lambda policy, path: write_stand_in(policy, path, 2, format=0), "format 0"),
        (
            lambda policy, path: (path / ex.EXPORT_DIR / "cpu_k2_b2" / ex.PACKAGE_FILE).write_bytes(b"other"),
            "is not the file its manifest describes",
        ),
        (
            lambda policy, path: (path / ex.EXPORT_DIR / "cpu_k2_b2" / ex.MANIFEST_FILE).write_text("{"),
            "manifest",
        ),
    ],
    ids=["weights", "config", "torch", "format", "package", "manifest"],
)
def test_a_mismatched_artefact_is_refused_with_a_log_line(checkpoint, caplog, change, reason):
    torch.manual_seed(0)
    change(ActionflowPolicy(small_config()), checkpoint)
    with caplog.at_level(logging.WARNING):
        policy = ActionflowPolicy.from_pretrained(checkpoint)
    assert f"not using the exported sampler {checkpoint / ex.EXPORT_DIR / 'cpu_k2_b2'}" in caplog.text
    assert reason in caplog.text
    assert policy.exported_samplers.keys() == []
    assert not used_artefact(chunk(policy))


def test_other_weights_in_the_checkpoint_refuse_the_artefact(checkpoint, caplog):
    torch.manual_seed(1)  # retrained: same architecture, other weights
    ActionflowPolicy(small_config()).save_pretrained(checkpoint)
    with caplog.at_level(logging.WARNING):
        policy = ActionflowPolicy.from_pretrained(checkpoint)
    assert "other weights than the policy's" in caplog.text
    assert not used_artefact(chunk(policy))


def guided_chunk(policy, k=2, batch_size=2, delay=1):
    """A chunk guided toward a leftover (as ``select_action`` and LeRobot's RTC engine ask)."""
    gen = torch.Generator().manual_seed(2)
    leftover = random_batch(policy.config, batch_size, gen)["action"][:, 3:]
    return policy.predict_action_chunk(
        random_batch(policy.config, batch_size, gen),
        num_inference_steps=k,
        inference_delay=delay,
        prev_chunk_left_over=leftover,
    )


def test_guided_chunks_use_the_guided_artefact(checkpoint):
    torch.manual_seed(0)
    write_stand_in(ActionflowPolicy(small_config()), checkpoint, k=2, guided=True)
    policy = ActionflowPolicy.from_pretrained(checkpoint)
    assert policy.exported_samplers.keys() == [PLAIN_K2, GUIDED_K2]
    assert used_artefact(guided_chunk(policy))
    # the plain inputs, then the leftover aligned with the chunk, its weights and the frozen mask
    assert StandInRunner.calls[-1][-3:] == [(2, 8, 10), (2, 8), (2, 8)]
    assert used_artefact(chunk(policy))
    assert len(StandInRunner.calls[-1]) == 5

    # select_action with the default guidance: the first chunk plain, the next guided
    policy.reset()
    policy.config.num_inference_steps = 2
    step = {k: v[:, 0] for k, v in random_batch(policy.config, 2, torch.Generator()).items() if k != "action"}
    for _ in range(2 * policy.config.n_action_steps):
        policy.select_action(step)
    assert [len(c) for c in StandInRunner.calls[-2:]] == [5, 8]


def test_guided_chunks_without_a_guided_artefact_sample_eagerly_and_say_so(checkpoint, caplog):
    policy = ActionflowPolicy.from_pretrained(checkpoint)
    with caplog.at_level(logging.INFO):
        assert not used_artefact(guided_chunk(policy))
    assert "no exported sampler for guided K=2 batch 2 on cpu (exported: K=2 batch 2 on cpu)" in caplog.text


def test_options_outside_the_sampler_keep_the_artefact(checkpoint):
    policy = ActionflowPolicy.from_pretrained(checkpoint, config=small_config(n_action_steps=2))
    assert used_artefact(chunk(policy))
    # the execution options decide which chunk is guided and how, not what a sampler computes
    execution = dict(guide_to_previous_chunk=False, execution_delay_steps=1, target_smoothing=0.5)
    policy = ActionflowPolicy.from_pretrained(checkpoint, config=small_config(**execution))
    assert used_artefact(chunk(policy))
    changed = ActionflowPolicy.from_pretrained(checkpoint, config=small_config(noise_sigma=0.2))
    assert not used_artefact(chunk(changed))


def test_weights_changed_after_loading_drop_the_artefact(checkpoint, caplog):
    policy = ActionflowPolicy.from_pretrained(checkpoint)
    policy.train()
    policy.eval()  # a mode switch alone changes no weight
    assert used_artefact(chunk(policy))
    policy.load_state_dict(policy.state_dict())  # the same weights, written again
    assert used_artefact(chunk(policy))
    with torch.no_grad():
        policy.network.head[1].bias.add_(0.1)  # e.g. an optimiser step
    with caplog.at_level(logging.WARNING):
        assert not used_artefact(chunk(policy))
    assert "weights changed since the exported sampler" in caplog.text


def test_save_pretrained_carries_the_artefact(checkpoint, tmp_path):
    policy = ActionflowPolicy.from_pretrained(checkpoint)
    policy.save_pretrained(tmp_path / "copy")
    shutil.rmtree(checkpoint)
    again = ActionflowPolicy.from_pretrained(tmp_path / "copy")
    assert used_artefact(chunk(again))


def test_export_refuses_bad_arguments(tmp_path):
    policy = ActionflowPolicy(small_config()).eval()
    with pytest.raises(ValueError, match="num_inference_steps"):
        ex.export_sampler(policy, tmp_path, 0)
    with pytest.raises(ValueError, match="device must be"):
        ex.export_sampler(policy, tmp_path, 2, device="mps")
    assert not (tmp_path / ex.EXPORT_DIR).exists()


def test_export_command_names_a_missing_checkpoint(tmp_path, capsys):
    from lerobot_actionflow.export import main

    assert main([str(tmp_path / "nowhere")]) == 2
    assert f"no checkpoint at {tmp_path / 'nowhere'}" in capsys.readouterr().err


@pytest.mark.parametrize("guided", [False, True], ids=["plain", "guided"])
def test_the_exported_programs_trace_to_the_eager_actions(guided):
    """Both programs go through ``torch.export`` (no data-dependent branch), and the traced graph
    gives ``predict_action_chunk``'s actions on the same observations, noise and leftover. (The
    AOTInductor build of the graph is the ``-m compile`` test below.)"""
    from lerobot_actionflow.policies.execution import rtc_config_of, rtc_guidance

    torch.manual_seed(0)
    policy = ActionflowPolicy(small_config()).eval()
    program = policy.sampler_program(policy, 2, guided)
    example = program.example_inputs(2, torch.device("cpu"))
    graph = torch.export.export(program, example, strict=False).module()

    gen = torch.Generator().manual_seed(4)
    batch = random_batch(policy.config, 2, gen)
    leftover = batch.pop("action")[:, 3:]
    noise = se3_flow.draw_local_noise(2, policy.config.horizon, 0.1, generator=gen)
    obs = policy.check_observation(batch)
    inputs = [obs["observation.poses"], obs["observation.state"], noise.r, noise.p, noise.g]
    rtc = {}
    if guided:
        guide = rtc_guidance(leftover, 1, policy.config.horizon, rtc_config_of(policy.config), batch_size=2)
        inputs += [guide.target, guide.weights, guide.frozen]
        rtc = {"inference_delay": 1, "prev_chunk_left_over": leftover}
    expected = policy.predict_action_chunk(batch, noise=noise, num_inference_steps=2, **rtc)
    assert (graph(*inputs) - expected).abs().max() <= 1e-5
    if guided:  # control: the same graph without the guidance's pull
        inputs[-2] = torch.zeros_like(inputs[-2])
        inputs[-1] = torch.zeros_like(inputs[-1])
        assert (graph(*inputs) - expected).abs().max() > 1e-2


@pytest.mark.compile
def test_exported_sampler_round_trip_equals_eager_and_is_equivariant(tmp_path, caplog):
    from lerobot_actionflow.export import main

    torch.manual_seed(0)
    ActionflowPolicy(small_config()).save_pretrained(tmp_path / "pretrained_model")
    # Checks exported == eager itself, to 1e-5, at each batch size, plain and guided.
    assert main([str(tmp_path), "--steps", "2", "--batch-sizes", "1", "3"]) == 0

    policy = ActionflowPolicy.from_pretrained(tmp_path / "pretrained_model")
    policy.save_pretrained(tmp_path / "copy")
    policy = ActionflowPolicy.from_pretrained(tmp_path / "copy")
    assert policy.exported_samplers.keys() == [
        ex.ArtefactKey("cpu", 2, b, guided) for b in (1, 3) for guided in (False, True)
    ]
    assert isinstance(policy.exported_samplers._runners[("cpu", 2, 3, True)], ex._Runner)
    gen = torch.Generator().manual_seed(3)
    batch = random_batch(policy.config, 3, gen)
    noise = se3_flow.draw_local_noise(3, policy.config.horizon, 0.1, generator=gen)
    a_exported = policy.predict_action_chunk(batch, noise=noise, num_inference_steps=2)
    eager = ActionflowPolicy.from_pretrained(tmp_path / "copy")
    eager.exported_samplers = None
    a_eager = eager.predict_action_chunk(batch, noise=noise, num_inference_steps=2)
    assert (a_exported - a_eager).abs().max() <= 1e-5

    # Equivariance through the exported path; the control (an untransformed result) must fail.
    r_d, p_d = _random_transform(gen, torch.float32)
    policy.config.num_inference_steps = 2
    pose, pose_t = _sample_twice(policy, batch, noise, r_d, p_d)
    assert _equivariance_error(pose, pose_t, r_d, p_d) <= 1e-4
    assert _equivariance_error(pose, pose, r_d, p_d) > 1e-2
    with caplog.at_level(logging.INFO):
        policy.predict_action_chunk(transform_batch(batch, r_d, p_d), num_inference_steps=4)
    assert "no exported sampler for K=4" in caplog.text

    # The guided artefact: eager's chunk, and the scene moved with the leftover moves the chunk.
    leftover = random_batch(policy.config, 3, gen)["action"][:, 3:]
    kw = dict(noise=noise, num_inference_steps=2, inference_delay=2)
    calls = len(policy.exported_samplers._reported_misses)
    a_guided = policy.predict_action_chunk(batch, prev_chunk_left_over=leftover, **kw)
    assert len(policy.exported_samplers._reported_misses) == calls  # no eager fallback
    a_eager = eager.predict_action_chunk(batch, prev_chunk_left_over=leftover, **kw)
    assert (a_guided - a_eager).abs().max() <= 1e-5
    moved = transform_batch({**batch, "action": leftover}, r_d, p_d)
    a_moved = policy.predict_action_chunk(
        {k: v for k, v in moved.items() if k != "action"}, prev_chunk_left_over=moved["action"], **kw
    )
    assert _equivariance_error(action_to_pose(a_guided), action_to_pose(a_moved), r_d, p_d) <= 1e-4
    a_unmoved = policy.predict_action_chunk(  # control: the leftover left where it was
        {k: v for k, v in moved.items() if k != "action"}, prev_chunk_left_over=leftover, **kw
    )
    assert _equivariance_error(action_to_pose(a_guided), action_to_pose(a_unmoved), r_d, p_d) > 1e-2


def test_export_command_finds_the_checkpoint_in_a_training_output(tmp_path):
    from lerobot_actionflow.export import resolve_pretrained_dir

    ckpt = tmp_path / "run" / "checkpoints" / "last" / "pretrained_model"
    ActionflowPolicy(small_config()).save_pretrained(ckpt)
    assert resolve_pretrained_dir(tmp_path / "run") == ckpt
    assert resolve_pretrained_dir(ckpt.parent) == ckpt
    assert resolve_pretrained_dir(ckpt) == ckpt
