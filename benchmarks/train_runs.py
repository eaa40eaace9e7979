"""The benchmarks' subprocesses: one command with its output in a log (:func:`run_logged`), and one
training run, finished once: started, or resumed after an interruption (:func:`train_run`).

A run is finished when its checkpoint at the final step exists (LeRobot's numbered folder,
``checkpoints/<step>``). A run interrupted after at least one checkpoint resumes from
``checkpoints/last`` with LeRobot's own ``--resume=true`` (weights, optimiser, scheduler, RNG and
step restored); one interrupted before its first checkpoint starts over.
"""

from __future__ import annotations

import shutil
import subprocess
import time
from pathlib import Path

from lerobot.common.train_utils import get_step_identifier

from lerobot_actionflow.demo import train_command


def run_logged(cmd: list[str], env: dict, log: Path, append: bool = False) -> float:
    """Run ``cmd`` with its output in ``log`` (appended to with ``append``); its wall time in
    seconds. A failure exits with the log's path."""
    print("$", " ".join(cmd), f"{'>>' if append else '>'} {log}", flush=True)
    log.parent.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    with log.open("a" if append else "w") as f:
        code = subprocess.run(cmd, env=env, stdout=f, stderr=subprocess.STDOUT).returncode
    if code != 0:
        raise SystemExit(f"failed ({code}): {' '.join(cmd[:3])} ...; see {log}")
    return time.perf_counter() - start


def final_checkpoint(run: Path, steps: int) -> Path:
    """``run/checkpoints/<steps>/pretrained_model`` (LeRobot's step folder name)."""
    return run / "checkpoints" / get_step_identifier(steps, steps) / "pretrained_model"


def train_run(run: Path, train_args: list[str], steps: int, log: Path, env: dict) -> float | None:
    """Train ``actionflow-train <train_args>`` (whose ``--output_dir`` is ``run`` and ``--steps`` is
    ``steps``) to its final checkpoint; the wall time of this call in seconds, or None when the run
    was already finished. The log is appended to, so a resumed run keeps its earlier lines."""
    if final_checkpoint(run, steps).exists():
        return None
    last = run / "checkpoints" / "last" / "pretrained_model"
    if last.exists():
        cmd = [*train_command(), "--resume=true", f"--config_path={last / 'train_config.json'}"]
    else:
        if run.exists():
            shutil.rmtree(run)  # interrupted before its first checkpoint
        cmd = [*train_command(), *train_args]
    wall = run_logged(cmd, env, log, append=True)
    if not final_checkpoint(run, steps).exists():
        raise SystemExit(f"training ended without its checkpoint {final_checkpoint(run, steps)}: see {log}")
    return wall
