#!/usr/bin/env bash
# A trained checkpoint judged as a candidate for the shipped network, by the numbers the shipped
# network is held to (docs/experiments.md's rules): exported and quantized as `make bundle`
# does, its selections fitted (or carried from the shipped bundle), then the real pairs (16
# and 8 LiDAR rows, and stereo only) and the rig's test split at 4 and 3 iterations, then its
# engine against the shipped one, alternated frame by frame, on this host's kernels and with
# OpenVINO's limited to AVX2.
#     bash experiments/judge_candidate.sh CHECKPOINT OUT_DIR [fit|carry]
# SHIPPED_FROM=runs/judge_X: the shipped bundle's evaluations taken from an earlier judgement
# (the same data and commands) instead of run again. ITERS=N: the candidate bundle's default
# iterations (exported and quantized at N; default 4), which its engine A/B runs at.
# JUDGE_ITERS="4": the iteration counts evaluated (default "4 3"); SPEED=0: no engine A/B
# (a control run of the shipped architecture and count, judged on accuracy only).
set -euo pipefail
CKPT=$1
OUT=$2
SELECTIONS=${3:-fit}
ITERS=${ITERS:-4}
JUDGE_ITERS=${JUDGE_ITERS:-4 3}
SPEED=${SPEED:-1}
BIN=${BIN:-.venv/bin}
BUNDLE="$OUT/bundle"
mkdir -p "$OUT"
echo "host: $(grep -o -w 'avx2\|avx512f\|avx512_vnni\|avx_vnni\|avx512_bf16\|amx_tile' /proc/cpuinfo | sort -u | tr '\n' ' ')($(nproc) cores)"
[ -d data/aloe ] || "$BIN/python" tools/real_pairs.py
[ -d data/motorcycle ] || "$BIN/python" tools/real_pairs.py --motorcycle
[ -d data/aloe_r8 ] || "$BIN/python" tools/real_pairs.py --rows 8 --out data/aloe_r8
[ -d data/motorcycle_r8 ] || "$BIN/python" tools/real_pairs.py --motorcycle --rows 8 --out data/motorcycle_r8
[ -d data/test16 ] || "$BIN/edge-depth" synth --out data/test16 --count 20 --seed 1000000 --lidar beams16
[ -d data/calib_mix ] || { "$BIN/edge-depth" synth --out data/calib_mix --count 8 --seed 500000 \
  && "$BIN/edge-depth" synth --world things --scene-folders --out data/calib_mix --count 8 --seed 900000; }
rm -rf "$BUNDLE"
"$BIN/python" tools/export.py "$CKPT" --out "$BUNDLE" --size 640x400 --iters "$ITERS"
"$BIN/python" tools/quantize.py "$BUNDLE" --calib data/calib_mix --eval data/test16 --iters "$ITERS"
if [ "$SELECTIONS" = carry ]; then
  "$BIN/python" tools/carry_selections.py edge/models/default/model.json "$BUNDLE"
else
  [ -d data/things_select ] || "$BIN/edge-depth" synth --world things --out data/things_select \
    --count 260 --seed 400000 --workers 2
  "$BIN/python" tools/fit_select.py "$BUNDLE" --data data/things_select
  "$BIN/python" tools/fit_edge_select.py "$BUNDLE" --data data/things_select
fi
for iters in $JUDGE_ITERS; do
  for data in aloe motorcycle aloe_r8 motorcycle_r8 test16; do
    for model in edge/models/default "$BUNDLE"; do
      tag=$(basename "$(dirname "$model")")_$(basename "$model")
      kept="${SHIPPED_FROM:-}/eval_${data}_${iters}_${tag}.json"
      if [ "$model" = edge/models/default ] && [ -n "${SHIPPED_FROM:-}" ] && [ -f "$kept" ]; then
        cp "$kept" "$OUT/"
        continue
      fi
      "$BIN/python" tools/evaluate.py "data/$data" --model "$model" --methods net --no-lidar \
        --runtime onnxruntime --precision int8 --iters "$iters" \
        --json "$OUT/eval_${data}_${iters}_${tag}.json" > /dev/null
    done
  done
done
"$BIN/python" - "$OUT" $JUDGE_ITERS <<'EOF'
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
print("| data | iters | shipped EPE / bad-3 | stereo only | candidate EPE / bad-3 | stereo only |")
print("|---|---|---|---|---|---|")
for iters in map(int, sys.argv[2:]):
    for data in ("aloe", "motorcycle", "aloe_r8", "motorcycle_r8", "test16"):
        cells = []
        for tag in ("models_default", f"{out.name}_bundle"):
            r = json.loads((out / f"eval_{data}_{iters}_{tag}.json").read_text())
            for key in ("net", "net-nolidar"):
                cells.append(f"{r[key]['epe']:.3f} / {r[key]['bad3']:.2f}" if key in r else "—")
        print(f"| {data} | {iters} | " + " | ".join(cells) + " |")
EOF
[ "$SPEED" = 0 ] && exit 0
"$BIN/python" experiments/bundle_engine_ab.py edge/models/default "$BUNDLE" --frames 40
ONEDNN_MAX_CPU_ISA=AVX2 "$BIN/python" experiments/bundle_engine_ab.py edge/models/default \
  "$BUNDLE" --frames 40 --bf16 off
