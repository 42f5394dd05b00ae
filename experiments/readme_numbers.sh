#!/usr/bin/env bash
# Re-measures every number of the README's Results section with the README's own commands:
# the real pairs and the rig's test split (tools/evaluate.py) and the speed (tools/bench.py
# --runs 3). Writes out/readme/*.json; prints the host's ISA first. Nothing else should run.
#   bash experiments/readme_numbers.sh
set -euo pipefail
BIN=${BIN:-.venv/bin}
OUT=out/readme
mkdir -p "$OUT" data
echo "host: $(grep -o -w 'avx2\|avx512f\|avx512_vnni\|avx_vnni\|avx512_bf16\|amx_tile' /proc/cpuinfo | sort -u | tr '\n' ' ')($(nproc) cores)"
date -u +%FT%TZ
[ -d data/aloe ] || "$BIN/python" tools/real_pairs.py
[ -d data/motorcycle ] || "$BIN/python" tools/real_pairs.py --motorcycle
[ -d data/test16 ] || "$BIN/edge-depth" synth --out data/test16 --count 20 --seed 1000000 --lidar beams16
for pair in aloe motorcycle; do
  "$BIN/python" tools/evaluate.py "data/$pair" --methods net,sgbm-filled,sgbm+lidar,lidar-nearest \
      --no-lidar --runtime onnxruntime --precision int8 --json "$OUT/$pair.json"
done
"$BIN/python" tools/evaluate.py data/test16 --methods net --no-lidar --runtime onnxruntime --precision int8 \
    --json "$OUT/test16.json"
"$BIN/python" tools/bench.py --runs 3 --json "$OUT/bench.json" --markdown "$OUT/bench.md"
date -u +%FT%TZ
for i in 1 2 3; do  # the daemon on the synthetic robot
  "$BIN/edge-depth" run --config experiments/sim_robot.toml --max-frames 100 | grep throughput
done
