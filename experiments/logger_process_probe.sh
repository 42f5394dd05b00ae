#!/usr/bin/env bash
# What logging costs the daemon's frame and what a logger process of its own would give back,
# with AVX2 kernels (experiments/avx2_kernels.sh): the daemon on the sim robot as shipped
# (logging in its frame), logging nothing, and logging nothing beside a stand-in logger process
# doing ~10 ms of a frame's compression and writing every 90 ms; three rounds, alternated.
#     bash experiments/logger_process_probe.sh
set -euo pipefail
BIN=${BIN:-.venv/bin}
run() { bash experiments/avx2_kernels.sh "$BIN/edge-depth" run --config "$1" --max-frames 100 2>&1 \
          | grep -oE 'throughput [0-9.]+ frames/s'; }
for i in 1 2 3; do
  echo "logging in the frame: $(run experiments/sim_robot.toml)"
  echo "logging nothing: $(run experiments/sim_robot_nolog.toml)"
  "$BIN/python" experiments/stand_in_logger.py 0.09 9 3 &
  sleep 0.5
  echo "logging nothing, a stand-in logger process beside it: $(run experiments/sim_robot_nolog.toml)"
  wait
done
