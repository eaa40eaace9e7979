"""SO(3)/SE(3) in pure torch: batched, dtype/device preserving, differentiable.

Nothing here imports LeRobot or robosuite.
"""

from lerobot_actionflow.geometry.quaternion import (
    axis_angle_to_matrix,
    matrix_to_axis_angle,
    matrix_to_quaternion,
    quaternion_multiply,
    quaternion_to_matrix,
    wxyz_to_xyzw,
    xyzw_to_wxyz,
)
from lerobot_actionflow.geometry.rotation6d import matrix_to_rotation_6d, rotation_6d_to_matrix
from lerobot_actionflow.geometry.so3 import (
    exp,
    geodesic_distance,
    hat,
    interpolate,
    log,
    project_to_so3,
    random_rotation,
    vee,
)
from lerobot_actionflow.geometry.validation import (
    check_finite,
    check_quaternion,
    check_rotation_matrix,
    rotation_error,
)

__all__ = [
    "axis_angle_to_matrix",
    "check_finite",
    "check_quaternion",
    "check_rotation_matrix",
    "exp",
    "geodesic_distance",
    "hat",
    "interpolate",
    "log",
    "matrix_to_axis_angle",
    "matrix_to_quaternion",
    "matrix_to_rotation_6d",
    "project_to_so3",
    "quaternion_multiply",
    "quaternion_to_matrix",
    "random_rotation",
    "rotation_6d_to_matrix",
    "rotation_error",
    "vee",
    "wxyz_to_xyzw",
    "xyzw_to_wxyz",
]
