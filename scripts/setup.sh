#!/usr/bin/env bash
# One-command set-up on a fresh machine: system packages, a Python 3.12 virtual environment at
# .venv in the repository root, the pinned dependencies of requirements.lock, robosuite, and
# this package (editable). Safe to run again: it skips what is already there.
set -euo pipefail
cd "$(dirname "$0")/.."

log() { printf '\n[setup] %s\n' "$*"; }

# 1. System packages: FFmpeg (torchcodec decodes LeRobot's videos with it), EGL for MuJoCo's
#    offscreen rendering.
missing=()
command -v ffmpeg >/dev/null 2>&1 || missing+=(ffmpeg)
ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1' || missing+=(libegl1)
if ((${#missing[@]})); then
    log "installing system packages: ${missing[*]}"
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# 2. Python >= 3.12 (LeRobot 0.6 does not parse on 3.11).
find_python() {
    local c
    for c in "${PYTHON:-}" python3.12 python3.13 python3 \
             "$HOME"/.pyenv/versions/3.12*/bin/python3.12 /usr/local/bin/python3.12 /usr/bin/python3.12; do
        [ -n "$c" ] || continue
        if "$c" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 12) else 1)' >/dev/null 2>&1; then
            command -v "$c" 2>/dev/null || echo "$c"
            return 0
        fi
    done
    return 1
}
if [ ! -x .venv/bin/python ]; then
    PY=$(find_python) || { echo "[setup] error: Python >= 3.12 not found (set PYTHON=/path/to/python3.12)" >&2; exit 1; }
    log "creating .venv with $PY ($("$PY" --version))"
    "$PY" -m venv .venv
fi

# 3. Pinned dependencies. The lock is a complete resolution, so --no-deps installs exactly it
#    (and lets robosuite in without its numpy<2 mink pin).
log "installing requirements.lock into .venv (first time: a few GB, several minutes)"
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --no-deps -r requirements.lock
.venv/bin/python -m pip install --quiet --no-deps --no-build-isolation -e .

# 4. Check the result: imports, and LeRobot's plugin scan finding us.
log "checking the install"
MUJOCO_GL=${MUJOCO_GL:-egl} .venv/bin/python - <<'PY'
import importlib.metadata as md
import lerobot, torch, robosuite, mujoco  # noqa: F401
import lerobot_policy_actionflow  # noqa: F401
print(f"lerobot {md.version('lerobot')}, torch {torch.__version__}, robosuite {robosuite.__version__}, "
      f"mujoco {mujoco.__version__}, lerobot_policy_actionflow {md.version('lerobot_policy_actionflow')}")
PY
log "done: activate with 'source .venv/bin/activate'"
