"""Evaluation tools on top of LeRobot's eval machinery: ``sweep``, success per number of
inference steps for trained checkpoints; ``latency`` and ``latency_sweep``, success and
smoothness (``smoothness``) when the env keeps stepping while the policy infers."""
