#!/usr/bin/env bash
# The test command: lint, then the whole suite, offline (the Hub is never contacted).
# Extra arguments go to pytest (e.g. `bash scripts/test.sh tests/geometry -x`).
set -euo pipefail
cd "$(dirname "$0")/.."
export HF_HUB_OFFLINE=1 HF_DATASETS_OFFLINE=1 WANDB_MODE=disabled
export MUJOCO_GL=${MUJOCO_GL:-egl} PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl}
.venv/bin/ruff check .
.venv/bin/ruff format --check .
# pytest exits 5 when it collects no test; set -e turns that into a failure too.
.venv/bin/python -m pytest "$@"
