"""Networks: Invariant Point Attention, the SE(3)-invariant transformer and ActionFlow's velocity
field, the adaptation module, image and point-cloud encoders. No LeRobot or robosuite imports."""

from lerobot_actionflow.nn.actionflow_network import ActionFlowNetwork, ObservationTokens
from lerobot_actionflow.nn.dp_transformer import DPTransformer
from lerobot_actionflow.nn.ipa import InvariantPointAttention, IPASize
from lerobot_actionflow.nn.point_tokens import PointGroupTokenizer
from lerobot_actionflow.nn.pointnet import PointNetEncoder
from lerobot_actionflow.nn.pose_adaptation import PoseAdaptation
from lerobot_actionflow.nn.se3_transformer import IPABlock, SE3InvariantTransformer

__all__ = [
    "ActionFlowNetwork",
    "DPTransformer",
    "IPABlock",
    "IPASize",
    "InvariantPointAttention",
    "ObservationTokens",
    "PointGroupTokenizer",
    "PointNetEncoder",
    "PoseAdaptation",
    "SE3InvariantTransformer",
]
