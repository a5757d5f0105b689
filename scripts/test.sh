#!/usr/bin/env bash
# Set up (see bootstrap.sh and ros2_venv.sh), lint, type-check (mypy, configured in
# setup.cfg), then run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
bash scripts/ros2_venv.sh  # the real ros2 command line for test/ros/test_ros2_cli.py (cached)
.venv/bin/ruff check strain_comp test bench scripts studies
.venv/bin/mypy
# two workers (pytest-xdist), each test file whole on one of them (its module fixtures, such
# as a colcon build, made once); test/ros_env.py gives each worker its own ROS domains;
# test/conftest.py compiles the numba kernels first (test/warm_kernels.py), once, not per worker
exec .venv/bin/python -m pytest -q -n 2 --dist loadfile "$@"
