"""The simulated robot ``actionflow_sim`` (config in :mod:`.config_actionflow_sim`, robot in
:mod:`.actionflow_sim`). Importing this package registers the robot type; the robot module
(which imports gymnasium and LeRobot's ``Robot``, not robosuite) is loaded when LeRobot builds
the robot."""

from lerobot_actionflow.robots.actionflow_sim.config_actionflow_sim import ActionFlowSimConfig

__all__ = ["ActionFlowSimConfig"]
