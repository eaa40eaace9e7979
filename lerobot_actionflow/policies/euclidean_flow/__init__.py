"""``euclidean_flow``: rectified-flow action-chunking policy (ActionFlow paper, App. B/E).

LeRobot's naming convention: ``configuration_euclidean_flow.EuclideanFlowConfig`` (registered as
``--policy.type=euclidean_flow``), ``modeling_euclidean_flow.EuclideanFlowPolicy``,
``processor_euclidean_flow.make_euclidean_flow_pre_post_processors``. Importing this package
only registers the config; the modeling module is imported by LeRobot's factory when needed.
"""

from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig

# The processor step every new checkpoint's preprocessor names: registered with the policy, so
# that loading a checkpoint's processors works in any process that can load its policy.
from lerobot_actionflow.robots import processor as _robot_observation_step  # noqa: F401

__all__ = ["EuclideanFlowConfig"]
