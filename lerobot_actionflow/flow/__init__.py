"""Flow matching: probability paths, target velocities, time grids and Euler solvers.

``se3``: SE(3) poses with a Euclidean gripper channel (ActionFlow); ``euclidean``: rectified
linear flow on flat vectors; ``schedules``: time grids shared by both. No LeRobot imports.
"""

from lerobot_actionflow.flow import euclidean, schedules, se3

__all__ = ["euclidean", "schedules", "se3"]
