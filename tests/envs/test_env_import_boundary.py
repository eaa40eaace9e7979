"""Importing the envs package (task table and gym ids) must not import robosuite or LeRobot:
``gym.make`` imports robosuite, the LeRobot config module imports LeRobot."""

import subprocess
import sys


def test_envs_package_import_is_light():
    code = (
        "import sys\n"
        "import lerobot_actionflow.envs as e\n"
        "assert len(e.GYM_IDS) >= 4, e.GYM_IDS\n"
        "heavy = [m for m in ('robosuite', 'lerobot', 'mujoco', 'torch') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
