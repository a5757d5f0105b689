#!/usr/bin/env bash
# Set up (see bootstrap.sh), lint, type-check (mypy, configured in setup.cfg), then run the
# whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
.venv/bin/ruff check strain_comp test bench scripts
.venv/bin/mypy
exec .venv/bin/python -m pytest -q "$@"
