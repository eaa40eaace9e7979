"""lerobot-actionflow: equivariant SE(3) flow-matching policies for LeRobot.

Subpackages: ``geometry`` (SO(3)/SE(3)), ``flow`` (flow matching), ``nn`` (networks) form the
core and never import LeRobot or robosuite; ``policies``, ``envs`` and ``data`` are the glue.
Importing this package is cheap; :func:`lerobot_actionflow.registry.register_all` registers the
LeRobot policy and env types (LeRobot's plugin scan calls it through
``lerobot_policy_actionflow``).
"""

__version__ = "0.1.0"
