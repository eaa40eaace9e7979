"""Suite-wide settings: the tests' models are tiny, so one intra-op thread is faster than two
(no OpenMP hand-offs) and leaves the second core to subprocesses such as lerobot-train."""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("MUJOCO_GL", "egl")

import torch

torch.set_num_threads(1)
