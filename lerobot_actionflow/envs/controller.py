"""The arm controller of every pose-token task: robosuite's OSC_POSE with absolute world targets.

``load_composite_controller_config(controller="BASIC", robot="Panda")`` gives an OSC_POSE arm
in *delta* mode with targets in the robot base frame. ActionFlow outputs absolute end-effector
poses in the world frame, so the arm part is switched to ``input_type="absolute"`` and
``input_ref_frame="world"``. In that mode robosuite reads the 6 arm inputs as
``[x, y, z, axis-angle (3)]`` (world frame) and applies no scaling or clipping; the env wrapper
converts the 6D rotation of an action to axis-angle and clips positions to the task workspace.
The gripper part (``GRIP``) takes one value in ``[-1, 1]``: -1 open, +1 closed.
"""

from __future__ import annotations

import copy
import functools
import logging


@functools.cache
def _base_config() -> dict:
    from robosuite.controllers import load_composite_controller_config

    logger = logging.getLogger("robosuite_logs")
    level = logger.level
    logger.setLevel(logging.WARNING)  # silence "Loading controller configuration from ..."
    try:
        cfg = load_composite_controller_config(controller="BASIC", robot="Panda")
    finally:
        logger.setLevel(level)
    # Keep only the parts a single Panda has; the others make robosuite warn at every make.
    cfg["body_parts"] = {"right": cfg["body_parts"]["right"]}
    arm = cfg["body_parts"]["right"]
    if arm["type"] != "OSC_POSE":
        raise RuntimeError(f"expected an OSC_POSE arm in robosuite's BASIC config, got {arm['type']}")
    arm["input_type"] = "absolute"
    arm["input_ref_frame"] = "world"
    return cfg


def absolute_pose_controller_config() -> dict:
    """A fresh copy of the composite controller config (BASIC, Panda, absolute world OSC_POSE)."""
    return copy.deepcopy(_base_config())
