"""Edge cases of the env's inputs: huge but finite actions, non-bool flags, empty images,
the scene-yaw bound as it is printed."""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

from lerobot_actionflow import rotations as R
from lerobot_actionflow.envs.scene_transform import SceneTransform


def _action_converter():
    """``PoseTokenEnv.to_robosuite_action`` bound to a stand-in holding only the workspace
    bounds it reads (no simulator needed)."""
    from lerobot_actionflow.envs.pose_env import PoseTokenEnv

    stub = types.SimpleNamespace(_ws_low=np.array([-1.0, -1.0, 0.0]), _ws_high=np.array([1.0, 1.0, 2.0]))
    return lambda a: PoseTokenEnv.to_robosuite_action(stub, a)


@pytest.mark.parametrize("scale", [1e155, 1e300, 1.7e308])
def test_huge_rot6d_entries_give_the_rotation_not_a_zero_matrix(scale):
    d6 = np.array([scale, 0.0, 0.0, 0.0, scale, 0.0])  # identity, scaled
    np.testing.assert_allclose(R.rotation_6d_to_matrix(d6), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(R.rotation_6d_to_matrix(d6[None]), np.eye(3)[None], atol=1e-12)
    action = np.r_[0.0, 0.0, 1.0, d6, 0.0]
    np.testing.assert_allclose(_action_converter()(action)[3:6], 0.0, atol=1e-12)  # no 180 deg turn


def test_small_rot6d_columns_are_still_refused():
    with pytest.raises(ValueError, match="zero first column"):
        R.rotation_6d_to_matrix(np.array([1e-9, 0, 0, 0, 1, 0]))
    with pytest.raises(ValueError, match="parallel or zero"):
        R.rotation_6d_to_matrix(np.array([[1.0, 0, 0, 1e308, 0, 0]]))


def test_huge_finite_positions_are_clipped_not_reported_non_finite():
    out = _action_converter()(np.r_[1e308, 1e308, 1e308, 1.0, 0, 0, 0, 1.0, 0, 0.0])
    np.testing.assert_allclose(out[:3], [1.0, 1.0, 2.0])
    with pytest.raises(ValueError, match=r"indices \[1\]"):
        _action_converter()(np.r_[0.0, np.nan, 0, 1.0, 0, 0, 0, 1.0, 0, 0.0])


def test_move_robot_must_be_a_bool():
    with pytest.raises(TypeError, match="move_robot must be a bool"):
        SceneTransform(yaw=0.1, move_robot="false")
    from lerobot_actionflow.envs.configuration import ActionFlowEnvConfig

    with pytest.raises(TypeError, match="scene_move_robot must be a bool"):
        ActionFlowEnvConfig(task="Lift", scene_yaw=(0.0, 0.1), scene_move_robot="false")


def test_yaw_bound_is_printed_exactly():
    with pytest.raises(ValueError) as e:
        SceneTransform(yaw=(0.0, 1.5708), move_robot=True)  # just above pi/2
    assert repr(math.pi / 2) in str(e.value)
    SceneTransform(yaw=(0.0, math.pi / 2), move_robot=True)  # the printed bound is accepted


def test_zero_image_size_is_refused():
    from lerobot_actionflow.envs.configuration import ActionFlowEnvConfig
    from lerobot_actionflow.envs.pose_env import PoseTokenEnv

    with pytest.raises(ValueError, match="image_height and image_width must be >= 1"):
        PoseTokenEnv("Lift", cameras=("wrist",), image_height=0)
    with pytest.raises(ValueError, match="observation_height must be >= 1"):
        ActionFlowEnvConfig(task="Lift", cameras="wrist", observation_height=0)
