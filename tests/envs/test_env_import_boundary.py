"""Import boundaries of the envs: the package import (task table and gym ids) must not import
robosuite or LeRobot (``gym.make`` imports robosuite, the LeRobot config module imports LeRobot),
and no env module but the LeRobot config imports torch or LeRobot."""

import subprocess
import sys


def _run(code: str) -> None:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]


def test_envs_package_import_is_light():
    _run(
        "import sys\n"
        "import lerobot_actionflow.envs as e\n"
        "assert len(e.GYM_IDS) >= 4, e.GYM_IDS\n"
        "heavy = [m for m in ('robosuite', 'lerobot', 'mujoco', 'torch') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )


def test_env_modules_import_neither_torch_nor_lerobot():
    _run(
        "import importlib, pkgutil, sys\n"
        "import lerobot_actionflow.envs as e\n"
        "mods = [m.name for m in pkgutil.iter_modules(e.__path__) if m.name != 'configuration']\n"
        "assert {'pose_env', 'scene_mover', 'arm_ik', 'rendering'} <= set(mods), mods\n"
        "for m in mods:\n"
        "    importlib.import_module(f'lerobot_actionflow.envs.{m}')\n"
        "heavy = [m for m in ('lerobot', 'torch') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
