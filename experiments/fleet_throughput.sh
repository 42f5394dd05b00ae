#!/usr/bin/env bash
# A fleet's recordings three ways on this machine: the single-file `replay` in a serial loop,
# `edge-depth fleet replay` on Ray local with 1 and 2 workers (1 engine thread each), and the
# same pointed at a two-node Ray cluster started here (a head and a second node, 1 CPU each).
#   bash experiments/fleet_throughput.sh [WORK_DIR] [COUNT] [FRAMES]
# Prints wall time and frames/s of each; nothing else should run meanwhile.
set -euo pipefail
WORK=${1:-/tmp/fleet_throughput}
COUNT=${2:-40}
FRAMES=${3:-30}
BIN=${BIN:-.venv/bin}
mkdir -p "$WORK/recs"
grep -o -w 'avx512_vnni\|avx_vnni\|avx512_bf16\|amx_tile' /proc/cpuinfo | sort -u | tr '\n' ' '
echo "($(nproc) cores)"
for i in $(seq 1 "$COUNT"); do
  f="$WORK/recs/rec$(printf %02d "$i").mcap"
  [ -f "$f" ] || "$BIN/edge-depth" synth --mcap "$f" --frames "$FRAMES" --seed $((2000000 + 100 * i)) >/dev/null
done
total=$((COUNT * FRAMES))
timed() {  # NAME COMMAND...: wall time and frames/s
  local name=$1; shift
  local t0=$(date +%s.%N)
  "$@" >"$WORK/$name.log" 2>&1 || true
  local t1=$(date +%s.%N)
  python3 -c "w=$t1-$t0; print(f'$name: {w:.1f} s, {$total/w:.2f} frames/s')"
}
serial() {
  rm -rf "$WORK/serial" && mkdir -p "$WORK/serial"
  for f in "$WORK"/recs/*.mcap; do
    "$BIN/edge-depth" replay "$f" --out "$WORK/serial/$(basename "$f")" --threads 1
  done
}
if [ -z "${CLUSTER_ONLY:-}" ]; then
timed serial serial
rm -rf "$WORK/w1" "$WORK/w2"
timed fleet-1-worker "$BIN/edge-depth" fleet replay "$WORK/recs" --out "$WORK/w1" --workers 1 --threads 1
timed fleet-2-workers "$BIN/edge-depth" fleet replay "$WORK/recs" --out "$WORK/w2" --workers 2 --threads 1
fi
rm -rf "$WORK/cluster"
# Ray >= 2.59 authenticates a cluster's nodes with a token: every node and the driver need
# RAY_AUTH_MODE=token and the same token (here ~/.ray/auth_token, one machine)
export RAY_AUTH_MODE=token
"$BIN/ray" get-auth-token --generate >/dev/null
"$BIN/ray" start --head --node-ip-address 127.0.0.1 --num-cpus 1 --port 6391 --include-dashboard false >/dev/null
"$BIN/ray" start --address 127.0.0.1:6391 --node-ip-address 127.0.0.1 --num-cpus 1 >/dev/null
timed fleet-two-node-cluster "$BIN/edge-depth" fleet replay "$WORK/recs" --out "$WORK/cluster" --address 127.0.0.1:6391 --workers 2 --threads 1
"$BIN/ray" stop --force >/dev/null
tail -1 "$WORK/w2.log" "$WORK/cluster.log"
