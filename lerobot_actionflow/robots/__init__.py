"""LeRobot robots: the pose-token tasks as robots for LeRobot's deployment tools.

``layout`` (a task's observation and action as named scalar features, the form a LeRobot robot
exposes), ``processor`` (the processor step that turns that flat observation back into the
dataset's features for a policy; ``prepare_checkpoint`` adds it to a saved checkpoint),
``realtime`` (a fixed-rate wall-clock loop) and ``actionflow_sim`` (the robot type
``--robot.type=actionflow_sim``).
"""
