#!/usr/bin/env bash
# Set up a fresh machine: a virtual environment in .venv with strain_comp and its test
# dependencies and the ROS 2 Jazzy wheels (the `ros` extra) installed (editable), at the
# versions pinned in constraints.txt (scripts/upgrade_constraints.sh moves them). Safe to run
# again. pip's output goes to .venv/bootstrap.log and is shown only if the installation fails.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
log=.venv/bootstrap.log
echo "setting up .venv (pip log: $log)" >&2
if ! { .venv/bin/python -m pip install --disable-pip-version-check --upgrade pip &&
       .venv/bin/python -m pip install --disable-pip-version-check -c constraints.txt \
         -e '.[test,ros]'; } >"$log" 2>&1
then
  tail -n 40 "$log" >&2
  echo "bootstrap: pip install failed (full log: $log)" >&2
  exit 1
fi
