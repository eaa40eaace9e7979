"""App. G.3's wrist-image trick as a processor step: black outside the centre when the gripper
is closed, untouched when open, decided per batch element and step; in both policies'
preprocessors when configured, and saved / reloaded with them."""

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_actionflow.policies.wrist_focus import WristFocusStep, focus_mask, gripper_opening
from lerobot_actionflow.schema import STATE_GRIPPER_INDICES

CAM = "observation.images.wrist"


def _state(openings):
    s = torch.zeros(*openings.shape, 11)
    s[..., STATE_GRIPPER_INDICES[0]] = openings / 2
    s[..., STATE_GRIPPER_INDICES[1]] = -openings / 2
    return s


def test_masked_when_closed_untouched_when_open_per_element():
    openings = torch.tensor([[0.08, 0.01], [0.012, 0.05]])  # (B=2, S=2)
    image = torch.rand(2, 2, 3, 40, 50) + 0.1
    step = WristFocusStep(camera=CAM, size=30, threshold=0.02)
    out = step.observation({CAM: image, "observation.state": _state(openings)})[CAM]
    assert torch.allclose(gripper_opening(_state(openings)), openings)
    for b, s in [(0, 0), (1, 1)]:  # open: untouched
        assert torch.equal(out[b, s], image[b, s])
    for b, s in [(0, 1), (1, 0)]:  # closed: only the central 30 x 30 square survives
        kept = out[b, s] != 0
        assert kept.sum() == 3 * 30 * 30
        assert kept[:, 5:35, 10:40].all()
        assert torch.equal(out[b, s, :, 5:35, 10:40], image[b, s, :, 5:35, 10:40])


def test_small_images_are_kept_whole_and_shapes_must_agree():
    img = torch.rand(1, 3, 20, 20)
    assert torch.equal(focus_mask(img, torch.tensor([True]), 30), img)
    step = WristFocusStep(camera=CAM)
    with pytest.raises(ValueError, match="different leading"):
        step.observation({CAM: torch.rand(2, 3, 8, 8), "observation.state": torch.zeros(3, 11)})
    with pytest.raises(ValueError, match=r"no image 'observation\.images\.wrist'"):
        step.observation({"observation.state": torch.zeros(11)})


@pytest.mark.parametrize("policy", ["actionflow", "euclidean_flow"])
def test_both_preprocessors_apply_it_and_reload_it(policy, tmp_path):
    inputs = {
        "observation.poses": PolicyFeature(FeatureType.STATE, (2, 7)),
        "observation.state": PolicyFeature(FeatureType.STATE, (11,)),
        CAM: PolicyFeature(FeatureType.VISUAL, (3, 40, 40)),
    }
    common = dict(
        input_features=inputs, output_features={"action": PolicyFeature(FeatureType.ACTION, (10,))},
        device="cpu", wrist_focus_camera=CAM,
    )  # fmt: skip
    if policy == "actionflow":
        from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig as Cfg
        from lerobot_actionflow.policies.actionflow.processor_actionflow import (
            make_actionflow_pre_post_processors as make,
        )
    else:
        from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import (
            EuclideanFlowConfig as Cfg,
        )
        from lerobot_actionflow.policies.euclidean_flow.processor_euclidean_flow import (
            make_euclidean_flow_pre_post_processors as make,
        )
    cfg = Cfg(**common)
    pre, _ = make(cfg, None)
    assert any(isinstance(s, WristFocusStep) for s in pre.steps)
    pre.save_pretrained(tmp_path)
    from lerobot.processor import PolicyProcessorPipeline

    reloaded = PolicyProcessorPipeline.from_pretrained(tmp_path, config_filename=f"{pre.name}.json")
    assert [type(s).__name__ for s in reloaded.steps] == [type(s).__name__ for s in pre.steps]
    with pytest.raises(ValueError, match=r"wrist_focus_camera 'observation\.images\.front' is not an image"):
        Cfg(**{**common, "wrist_focus_camera": "observation.images.front"}).validate_features()
