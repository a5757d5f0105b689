#!/usr/bin/env bash
# The main job on built-in defaults: the bundled bag through the bundled calibration,
# printing the error table (strain_comp's `evaluate`).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
exec .venv/bin/strain-comp evaluate bags/demo_rates.mcap --calibration config/demo_calibration.yaml "$@"
