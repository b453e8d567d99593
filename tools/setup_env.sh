#!/usr/bin/env bash
# Create or refresh the project's virtual environment and the system libraries it needs.
# Usage: tools/setup_env.sh PYTHON VENV
set -euo pipefail
PYTHON="${1:-python3}"
VENV="${2:-.venv}"
PIP="$VENV/bin/pip"

if [ ! -x "$VENV/bin/python" ]; then
    "$PYTHON" -m venv "$VENV"
fi
export PIP_DISABLE_PIP_VERSION_CHECK=1

# torch: prefer a CPU build. A local "+cpu" wheel (found through pip's find-links) first, then
# PyTorch's CPU index, then whatever PyPI serves.
if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
    "$PIP" install -q "torch==2.13.0+cpu" 2>/dev/null \
    || "$PIP" install -q --timeout 30 torch --index-url https://download.pytorch.org/whl/cpu \
           --extra-index-url https://pypi.org/simple 2>/dev/null \
    || "$PIP" install -q torch
fi

# test: pytest and the notebook runner; ray: the optional Ray backend of the run grids, so that the
# tests cover it (goflow itself runs without it: learning/execution.py imports it only for --ray);
# mujoco: gymnasium's originals for the locomotion envs' fidelity test; sb3: SAC for the estimates'
# policies (both benchmark-only).
"$PIP" install -q -e ".[test,ray,mujoco,sb3]" || {
    echo "setup_env: the mujoco or sb3 extra did not install; the tests that need them will skip" >&2
    "$PIP" install -q -e ".[test,ray]"
}

# Drake's VTK renderer draws headless through EGL/OSMesa; install the runtime libraries only if
# the import or a tiny render fails (Debian/Ubuntu package names).
if ! "$VENV/bin/python" tools/check_render.py >/dev/null 2>&1; then
    echo "setup_env: rendering check failed; installing system libraries for headless rendering" >&2
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -q
    $SUDO apt-get install -y -q libegl1 libgl1 libx11-6 libsm6 libxt6 libglib2.0-0 libgomp1
    "$VENV/bin/python" tools/check_render.py
fi
