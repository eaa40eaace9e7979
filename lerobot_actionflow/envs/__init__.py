"""Pose-token manipulation tasks on robosuite, as Gymnasium envs and a LeRobot env type.

Importing this package registers the task table (:mod:`.tasks`) and one Gymnasium id per task,
``lerobot_actionflow/<Task>-v0``; it does not import robosuite (``gym.make`` does). The LeRobot
env config (``--env.type=actionflow``) lives in :mod:`.configuration`.

Modules: ``tasks`` (registry), ``robomimic_tasks`` / ``mimicgen_tasks`` / ``mug_hang_tasks`` (the
task table), ``pose_env`` (the Gymnasium env), ``controller`` (absolute OSC_POSE),
``scene_transform`` (its parameters) and ``scene_mover`` (applying it to a scene), ``arm_ik``
(inverse kinematics of the arm), ``rendering`` (offscreen camera images), ``point_cloud`` and
``point_cloud_config`` (the fused depth-camera point cloud and its settings), ``progress`` (an
episode's sub-goals reached and closest approach to a joint limit), ``registration``,
``configuration``; robosuite environments written here: ``tabletop`` (their base),
``stack_three``, ``threading_task``, ``three_piece_assembly``, ``coffee``, ``mug_hang``
(``materials``: shared helpers). Keys and shapes come from :mod:`lerobot_actionflow.schema`,
rotations from :mod:`lerobot_actionflow.rotations`.
"""

import importlib

from lerobot_actionflow.envs.point_cloud_config import PointCloudConfig
from lerobot_actionflow.envs.registration import register_gym_envs
from lerobot_actionflow.envs.scene_transform import SceneTransform
from lerobot_actionflow.envs.tasks import TASKS, Entity, TaskSpec, get_task

# Fill the task table, robomimic's tasks first (this order is the order of GYM_IDS).
for _module in ("robomimic_tasks", "mimicgen_tasks", "mug_hang_tasks"):
    importlib.import_module(f"{__name__}.{_module}")

GYM_IDS: list[str] = register_gym_envs()

__all__ = ["GYM_IDS", "TASKS", "Entity", "PointCloudConfig", "SceneTransform", "TaskSpec", "get_task"]
