"""Tests of the euclidean_flow policy, its transformer, the IS sweep and the LeRobot CLIs."""
