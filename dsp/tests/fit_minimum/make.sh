#!/bin/sh
# Regenerates the records of ../fit_minimum.rs with the simulator: the Table 2
# adjusted driveline (config/examples/table2-adjusted.toml) with the load's onset at
# 0.15 s, 0.75 s of record, the static torque and the spindles' gap of each record,
# noise 0.5 kN*m, seed 1 (docs/measured.md, "What a burst of bites costs").
# usage (from the workspace root):
#   dsp/tests/fit_minimum/make.sh MILLGATE_BINARY            this suite's four records
#   dsp/tests/fit_minimum/make.sh MILLGATE_BINARY FOLDER "STATIC GAP" ...
#       others into FOLDER (kN*m, mrad), for MILLGATE_FIT_RECORDS=FOLDER
set -eu
bin=$1
here=$(dirname "$0")
if [ $# -ge 2 ]; then
  out=$2
  shift 2
else
  out=$here
  shift 1
fi
if [ $# -eq 0 ]; then
  set -- "150 0" "80 3" "80 0" "112 0"
fi
model=$(mktemp)
trap 'rm -f "$model"' EXIT
for case in "$@"; do
  set -- $case
  sed -e "s/^static_torque = .*/static_torque = $1.0/" \
      -e "s/^onset = .*/onset = 0.15/" \
      -e "s/^duration = .*/duration = 0.75/" \
      -e "s/^damping = 5.0e3$/damping = 5.0e3\nbacklash = $2.0e-3/" \
      config/examples/table2-adjusted.toml > "$model"
  grep -q "^backlash = $2.0e-3" "$model"
  "$bin" sim transient --model "$model" --noise-rms 0.5 --seed 1 \
      --out "$out/static$1-gap$2mrad.csv"
done
