"""ActionFlow's training loss: ``translation_scale`` sets the unit of the translation term, so a
scale ``s`` weights translation errors ``(s / 10)^2`` as much as the default, and
``loss_weight_translation = (10 / s)^2`` restores the default's loss exactly."""

import pytest
import torch

from lerobot_actionflow.flow import se3 as se3_flow
from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy

from .helpers import random_batch, small_config


def _loss_terms(batch, translation_scale, loss_weight_translation=1.0):
    """The loss of a policy whose network predicts a fixed velocity (0.1 everywhere), so that the
    terms depend on the targets and the scale only; the same noise and times for every call."""
    torch.manual_seed(0)
    policy = ActionflowPolicy(
        small_config(translation_scale=translation_scale, loss_weight_translation=loss_weight_translation)
    )

    def fixed_velocity(encoded, x, t=None, **_):
        return se3_flow.PoseVelocity(
            torch.full_like(x.p, 0.1), torch.full_like(x.p, 0.1), torch.full_like(x.g, 0.1)
        )

    policy.network.velocity = fixed_velocity
    torch.manual_seed(1)
    loss, terms = policy.forward(batch)
    return loss.item(), terms


@pytest.mark.parametrize("scale", [1.0, 3.0, 30.0])
def test_the_translation_term_scales_with_the_square_of_the_translation_scale(scale):
    batch = random_batch(small_config(), 8, torch.Generator().manual_seed(0))
    ref_loss, ref = _loss_terms(batch, 10.0)
    loss, terms = _loss_terms(batch, scale)
    assert terms["loss_translation"] == pytest.approx(ref["loss_translation"] * (scale / 10) ** 2, rel=1e-5)
    for name in ("loss_rotation", "loss_gripper"):
        assert terms[name] == pytest.approx(ref[name], rel=1e-6)
    # The control: an unweighted smaller (larger) scale gives a smaller (larger) loss.
    assert loss != pytest.approx(ref_loss, rel=1e-3)
    restored, _ = _loss_terms(batch, scale, loss_weight_translation=(10 / scale) ** 2)
    assert restored == pytest.approx(ref_loss, rel=1e-5)
