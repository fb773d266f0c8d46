#!/usr/bin/env bash
# Run a command inside the repository's .venv, creating or updating it first when needed.
#
#   bash scripts/venv.sh python scripts/simulate_chain.py
#   bash scripts/venv.sh python -m pytest
#
# Idempotent: the venv is rebuilt only when pyproject.toml, this script or the compiled kinematics' C source
# changed since the last install, so a second run installs nothing. Torch: the CPU wheel torch==2.13.0 is
# installed first (on these machines it is a local file); an unpinned request would download a multi-GB CUDA
# build. See README for GPU installs. The install compiles seqdex_drake/robots/_kinematics.c: it needs a C
# compiler and Python's headers (.ci/run installs gcc and python3-dev where they are missing).
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$repo/.venv"
python_bin="${SEQDEX_PYTHON:-python3.11}"
if ! command -v "$python_bin" >/dev/null 2>&1; then
  python_bin=python3
fi
stamp="$venv/.seqdex-install-stamp"
# The compiled kinematics' source too: an edited _kinematics.c is rebuilt by the editable install below.
want="$(cat "$repo/pyproject.toml" "$repo/scripts/venv.sh" "$repo/seqdex_drake/robots/_kinematics.c" | sha256sum \
  | cut -d' ' -f1)"

if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ] || [ ! -x "$venv/bin/python" ]; then
  echo "[venv.sh] setting up $venv (first run, or pyproject.toml or the C source changed)" >&2
  "$python_bin" - <<'PY' || { echo "[venv.sh] error: Python >= 3.11 is required (set SEQDEX_PYTHON to one)." >&2; exit 2; }
import sys
sys.exit(0 if sys.version_info >= (3, 11) else 1)
PY
  [ -x "$venv/bin/python" ] || "$python_bin" -m venv "$venv"
  "$venv/bin/python" -m pip install --quiet --upgrade pip
  if ! "$venv/bin/python" -c "import torch" >/dev/null 2>&1; then
    "$venv/bin/python" -m pip install --quiet "torch==2.13.0"
  fi
  "$venv/bin/python" -m pip install --quiet -e "$repo[dev,distributed]"
  echo "$want" > "$stamp"
fi
cd "$repo"
exec "$venv/bin/$1" "${@:2}"
