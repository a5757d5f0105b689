#!/usr/bin/env bash
# The real ROS 2 command line (ros2 run|launch|param|service|topic) in .venv-ros2, for the
# tests that drive the colcon-built package through it (test/ros/test_ros2_cli.py): built by the
# kit ../shared/ros2cli/make_venv.sh (STRAIN_COMP_ROS2CLI names another folder) with Python
# 3.12, Jazzy's, where installed (else python3), plus strain_comp's run requirements, and in
# .venv-ros2/setuptools68 Ubuntu 24.04's setuptools (the venv has the ROS wheels' >= 76) so
# the tests build the package with both.
# Cached: a second run compares a stamp and returns at once. Without the kit it says so and
# exits 0 (those tests then skip), except under CI=true, where it fails.
set -euo pipefail
cd "$(dirname "$0")/.."
KIT=${STRAIN_COMP_ROS2CLI:-../shared/ros2cli}
VENV=.venv-ros2
if [ ! -f "$KIT/make_venv.sh" ]; then
  if [ "${CI:-}" = true ]; then
    echo "ros2_venv: no ros2cli kit at $KIT (CI runs the ros2 command-line tests)" >&2
    exit 1
  fi
  echo "ros2_venv: no ros2cli kit at $KIT: the ros2 command-line tests will skip" >&2
  exit 0
fi
requirements() {  # setup.py's install_requires, one a line
  python3 -c 'import ast, sys
for n in ast.walk(ast.parse(open("setup.py").read())):
    if isinstance(n, ast.keyword) and n.arg == "install_requires":
        print("\n".join(ast.literal_eval(n.value)))'
}
stamp=$( { cat "$KIT/make_venv.sh"; ls "$KIT/wheels"; requirements; cat constraints.txt; } | sha1sum | cut -d' ' -f1)
if [ -f "$VENV/.stamp" ] && [ "$(cat "$VENV/.stamp")" = "$stamp" ]; then
  exit 0
fi
PY=python3
for candidate in python3.12 "$(pyenv root 2>/dev/null || echo /nonexistent)"/versions/3.12*/bin/python3.12; do
  if "$candidate" -c 'import sys; assert sys.version_info[:2] == (3, 12)' 2>/dev/null; then
    PY=$candidate
    break
  fi
done
rm -rf "$VENV"
mkdir -p "$VENV"
log=$VENV/build.log
echo "ros2_venv: building $VENV with $PY (log: $log)" >&2
if ! { bash "$KIT/make_venv.sh" "$VENV" "$PY" &&
       mapfile -t reqs < <(requirements) &&
       "$VENV/bin/python" -m pip install --disable-pip-version-check -q -c constraints.txt \
         "${reqs[@]}" &&
       "$VENV/bin/python" -m pip install --disable-pip-version-check -q --no-deps \
         --target "$VENV/setuptools68" setuptools==68.1.2; } >"$log" 2>&1
then
  tail -n 30 "$log" >&2
  echo "ros2_venv: failed (full log: $log)" >&2
  exit 1
fi
echo "$stamp" >"$VENV/.stamp"
