#!/usr/bin/env bash
# Move constraints.txt to the newest releases: rebuild .venv without the pins, write the
# versions it got into constraints.txt, then run the whole suite (scripts/test.sh) on them.
# Commit constraints.txt only when the suite passes.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
"$PYTHON" -m venv --clear .venv
.venv/bin/python -m pip install --disable-pip-version-check -q --upgrade pip
.venv/bin/python -m pip install --disable-pip-version-check -q -e '.[test,ros]'
{
  sed -n '1,/^[^#]/{/^#/p}' constraints.txt
  .venv/bin/python -m pip freeze --exclude-editable
} >constraints.txt.new
mv constraints.txt.new constraints.txt
git --no-pager diff --stat -- constraints.txt || true
bash scripts/test.sh
