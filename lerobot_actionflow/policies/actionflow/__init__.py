"""ActionFlow policy (LeRobot type ``actionflow``)."""

from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig

# The processor step every new checkpoint's preprocessor names: registered with the policy, so
# that loading a checkpoint's processors works in any process that can load its policy.
from lerobot_actionflow.robots import processor as _robot_observation_step  # noqa: F401

__all__ = ["ActionflowConfig"]
