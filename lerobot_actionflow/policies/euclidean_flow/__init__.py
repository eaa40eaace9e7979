"""``euclidean_flow``: rectified-flow action-chunking policy (ActionFlow paper, App. B/E).

LeRobot's naming convention: ``configuration_euclidean_flow.EuclideanFlowConfig`` (registered as
``--policy.type=euclidean_flow``), ``modeling_euclidean_flow.EuclideanFlowPolicy``,
``processor_euclidean_flow.make_euclidean_flow_pre_post_processors``. Importing this package
only registers the config; the modeling module is imported by LeRobot's factory when needed.
"""

from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig

__all__ = ["EuclideanFlowConfig"]
