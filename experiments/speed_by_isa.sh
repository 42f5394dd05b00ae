#!/usr/bin/env bash
# The README's Speed rows for this host's own kernels and for an AVX2-only CPU's kernels
# (experiments/avx2_kernels.sh): `tools/bench.py --runs 3`, three daemon runs on the sim
# robot (serial, the default, and pipelined) and three replays of a 70-frame sim recording
# each, the two kinds alternated. Writes out/isa/*; nothing else should run.
#   bash experiments/speed_by_isa.sh
set -euo pipefail
BIN=${BIN:-.venv/bin}
OUT=out/isa
mkdir -p "$OUT"
echo "host: $(grep -o -w 'avx2\|avx512f\|avx512_vnni\|avx_vnni\|avx512_bf16\|amx_tile' /proc/cpuinfo | sort -u | tr '\n' ' ')($(nproc) cores)"
date -u +%FT%TZ
[ -f "$OUT/sim70_0001.mcap" ] || "$BIN/edge-depth" record --config experiments/sim_robot.toml \
    --out "$OUT/sim70.mcap" --max-frames 70 > /dev/null
"$BIN/python" tools/bench.py --runs 3 --json "$OUT/bench_native.json" --markdown "$OUT/bench_native.md" | tail -12
bash experiments/avx2_kernels.sh "$BIN/python" tools/bench.py --runs 3 --json "$OUT/bench_avx2.json" \
    --markdown "$OUT/bench_avx2.md" | tail -12
for i in 1 2 3; do
  echo "native: $("$BIN/edge-depth" run --config experiments/sim_robot.toml --max-frames 100 2>&1 | grep throughput)"
  echo "avx2:   $(bash experiments/avx2_kernels.sh "$BIN/edge-depth" run --config experiments/sim_robot.toml --max-frames 100 2>&1 | grep throughput)"
done
for i in 1 2 3; do
  for kernels in native avx2; do
    [ $kernels = avx2 ] && run="bash experiments/avx2_kernels.sh" || run=""
    echo "$kernels pipelined: $($run "$BIN/edge-depth" run --config experiments/sim_robot_pipelined.toml \
        --max-frames 100 2>&1 | grep throughput)"
    echo "$kernels replay: $($run "$BIN/edge-depth" replay "$OUT/sim70_0001.mcap" \
        --out "$OUT/sim70_depth.mcap" 2>&1 | grep throughput | cut -d';' -f1)"
  done
done
date -u +%FT%TZ
