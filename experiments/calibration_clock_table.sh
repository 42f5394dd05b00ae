#!/bin/sh
# The calibration watch's clock table (docs/calibration.md): for each seed, a sim robot turning
# ±3° whose LiDAR stamps are 30 ms late, 30 ms early and right, checked after 100 frames as the
# daemon samples them.
#     sh experiments/calibration_clock_table.sh [SEEDS] [WORK_DIR]
set -e
SEEDS=${1:-"1000000 2000000 3000000 4000000 5000000"}
WORK=${2:-$(mktemp -d)}
BIN=${BIN:-.venv/bin}
for seed in $SEEDS; do
  for late in 30 -30 0; do
    rec="$WORK/turn_${seed}_${late}.mcap"
    "$BIN/edge-depth" synth --mcap "$rec" --frames 100 --seed "$seed" --turn-deg 3 \
      --lidar-late-ms "$late" > /dev/null
    printf 'seed %s, stamps late %s ms: ' "$seed" "$late"
    "$BIN/edge-depth" calibrate check "$rec" --every 13 2>&1 | grep "rotation error" || true
  done
done
