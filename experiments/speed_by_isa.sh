#!/usr/bin/env bash
# The README's Speed rows for this host's own kernels and for an AVX2-only CPU's kernels
# (experiments/avx2_kernels.sh): `tools/bench.py --runs 3` and three daemon runs on the sim
# robot each, the two kinds alternated. Writes out/isa/*; nothing else should run.
#   bash experiments/speed_by_isa.sh
set -euo pipefail
BIN=${BIN:-.venv/bin}
OUT=out/isa
mkdir -p "$OUT"
echo "host: $(grep -o -w 'avx2\|avx512f\|avx512_vnni\|avx_vnni\|avx512_bf16\|amx_tile' /proc/cpuinfo | sort -u | tr '\n' ' ')($(nproc) cores)"
date -u +%FT%TZ
"$BIN/python" tools/bench.py --runs 3 --json "$OUT/bench_native.json" --markdown "$OUT/bench_native.md" | tail -12
bash experiments/avx2_kernels.sh "$BIN/python" tools/bench.py --runs 3 --json "$OUT/bench_avx2.json" \
    --markdown "$OUT/bench_avx2.md" | tail -12
for i in 1 2 3; do
  echo "native: $("$BIN/edge-depth" run --config experiments/sim_robot.toml --max-frames 100 2>&1 | grep throughput)"
  echo "avx2:   $(bash experiments/avx2_kernels.sh "$BIN/edge-depth" run --config experiments/sim_robot.toml --max-frames 100 2>&1 | grep throughput)"
done
date -u +%FT%TZ
