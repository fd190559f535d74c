#!/usr/bin/env bash
# Set up (or refresh) the virtual environment at .venv/ with staticdepth installed editable.
# Idempotent: re-runs only when pyproject.toml/setup.py changed. Usage: bash setup.sh
set -euo pipefail
cd "$(dirname "$0")"
PY=${PYTHON:-python3}
stamp=.venv/.staticdepth-setup
want=$(cat pyproject.toml setup.py | sha256sum | cut -d' ' -f1)
if [ -x .venv/bin/python ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
  exit 0
fi
"$PY" -c 'import sys; sys.exit(sys.version_info < (3, 10))' || {
  echo "setup.sh: Python >= 3.10 is needed ($("$PY" --version 2>&1))" >&2; exit 2; }
[ -x .venv/bin/python ] || "$PY" -m venv .venv
# The CPU build of torch first: a bare 'torch' requirement would pull a multi-GB CUDA build.
# A local CPU wheel (a wheelhouse in pip's find-links) is used when there is one; else PyTorch's CPU index.
.venv/bin/python -m pip install -q --no-index --no-deps "torch==2.13.0" 2>/dev/null ||
  .venv/bin/python -m pip install -q "torch==2.13.0" --index-url https://download.pytorch.org/whl/cpu
# Everything, optional extras included (transformers, depthai, pycolmap, ray): the tests use them.
.venv/bin/python -m pip install -q -e ".[test,all]"
echo "$want" > "$stamp"
echo "setup.sh: ready (.venv/bin/staticdepth)"
