#!/usr/bin/env bash
# Regenerate the bundled bags (bags/) and the calibrations fitted on them (config/), all with
# the virtual test rig and the strain-comp command line. Deterministic: fixed seeds.
#   bags/train_random.mcap, bags/train_patterns.mcap  training data (random ramps, patterns)
#   bags/demo_rates.mcap     held-out rate sweep: what the README's demo evaluates
#   bags/steps.mcap          held-out steps with holds (relaxation)
#   bags/array_train.mcap, bags/array.mcap   a 6-sensor array, training and held-out
set -euo pipefail
cd "$(dirname "$0")/.."
SC="${STRAIN_COMP:-strain-comp}"
$SC simulate --scenario random   --seed 1 --out bags/train_random.mcap
$SC simulate --scenario patterns --seed 4 --out bags/train_patterns.mcap
$SC simulate --scenario rates    --seed 2 --out bags/demo_rates.mcap
$SC simulate --scenario steps    --seed 3 --out bags/steps.mcap
$SC simulate --scenario array    --seed 6 --out bags/array_train.mcap
$SC simulate --scenario array    --seed 5 --out bags/array.mcap
$SC fit bags/train_random.mcap bags/train_patterns.mcap --model apl --sensor all \
    --out config/demo_calibration.yaml
$SC fit bags/array_train.mcap --model apl --sensor all --out config/array_calibration.yaml
