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
