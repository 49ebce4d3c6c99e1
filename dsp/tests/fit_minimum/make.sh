#!/bin/sh
# Regenerates the records of ../fit_minimum.rs with the simulator: the Table 2
# adjusted driveline (config/examples/table2-adjusted.toml) with the load's onset at
# 0.15 s, 0.75 s of record, the static torque and the spindles' gap of each record,
# noise 0.5 kN*m, seed 1 (docs/measured.md, "What a burst of bites costs").
# usage: dsp/tests/fit_minimum/make.sh MILLGATE_BINARY   (from the workspace root)
set -eu
bin=$1
here=$(dirname "$0")
model=$(mktemp)
trap 'rm -f "$model"' EXIT
for case in "150 0" "80 3" "80 0" "112 0"; do
  set -- $case
  sed -e "s/^static_torque = .*/static_torque = $1.0/" \
      -e "s/^onset = .*/onset = 0.15/" \
      -e "s/^duration = .*/duration = 0.75/" \
      -e "s/^damping = 5.0e3$/damping = 5.0e3\nbacklash = $2.0e-3/" \
      config/examples/table2-adjusted.toml > "$model"
  grep -q "^backlash = $2.0e-3" "$model"
  "$bin" sim transient --model "$model" --noise-rms 0.5 --seed 1 \
      --out "$here/static$1-gap$2mrad.csv"
done
