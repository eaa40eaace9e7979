"""ActionFlow policy (LeRobot type ``actionflow``)."""

from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig

__all__ = ["ActionflowConfig"]
