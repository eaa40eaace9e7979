"""Evaluation tools on top of LeRobot's eval machinery: ``sweep``, success per number of
inference steps for trained checkpoints."""
