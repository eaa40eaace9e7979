"""The core (geometry, flow, nn) must not import LeRobot or robosuite."""

import ast
from pathlib import Path

import lerobot_actionflow

CORE = ("geometry", "flow", "nn")
FORBIDDEN = ("lerobot", "robosuite", "mujoco")


def test_core_modules_import_neither_lerobot_nor_robosuite():
    root = Path(lerobot_actionflow.__file__).parent
    offenders = []
    for sub in CORE:
        for path in (root / sub).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                names = []
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module:
                    names = [node.module]
                offenders += [f"{path.relative_to(root)}: {n}" for n in names if n.split(".")[0] in FORBIDDEN]
    assert not offenders, offenders
    assert any((root / sub).rglob("*.py") for sub in CORE)


def test_simulator_side_modules_import_no_torch():
    """The schema, the numpy rotations and the experts run beside the simulator (envs, data
    collection, evaluation workers): importing them must not import torch or LeRobot."""
    import subprocess
    import sys

    code = (
        "import importlib, pkgutil, sys\n"
        "import lerobot_actionflow.schema, lerobot_actionflow.rotations, lerobot_actionflow.experts as x\n"
        "for m in pkgutil.iter_modules(x.__path__):\n"
        "    importlib.import_module(f'lerobot_actionflow.experts.{m.name}')\n"
        "heavy = [m for m in ('torch', 'lerobot') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]
