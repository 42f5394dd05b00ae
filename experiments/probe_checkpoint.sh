#!/usr/bin/env bash
# A quick look at a training run's checkpoint on the numbers it will be judged by, before the
# full judgement (experiments/judge_candidate.sh): exported in fp32 (no quantization), the
# shipped bundle's fitted selections carried over, then the real pairs (16 and 8 LiDAR rows,
# and stereo only) and the rig's test split at 4 iterations on ONNX Runtime.
#     bash experiments/probe_checkpoint.sh runs/distil12/last.pt runs/probe_distil12
set -euo pipefail
CKPT=$1
OUT=$2
BIN=${BIN:-.venv/bin}
BUNDLE="$OUT/bundle"
mkdir -p "$OUT"
step=$("$BIN/python" -c "import sys, torch; print(torch.load(sys.argv[1], weights_only=False, map_location='cpu')['step'])" "$CKPT")
echo "$CKPT at step $step; host: $(grep -o -w 'avx2\|avx512f\|avx512_vnni\|avx512_bf16' /proc/cpuinfo | sort -u | tr '\n' ' ')"
rm -rf "$BUNDLE"
"$BIN/python" tools/export.py "$CKPT" --out "$BUNDLE" --size 640x400 --iters 4 > /dev/null
"$BIN/python" tools/carry_selections.py edge/models/default/model.json "$BUNDLE" > /dev/null
echo "| data | EPE / bad-3 | stereo only |"
echo "|---|---|---|"
for data in aloe motorcycle aloe_r8 motorcycle_r8 test16; do
  "$BIN/python" tools/evaluate.py "data/$data" --model "$BUNDLE" --methods net --no-lidar \
    --runtime onnxruntime --precision fp32 --iters 4 --json "$OUT/eval_${data}_${step}.json" \
    > /dev/null 2>&1
  "$BIN/python" - "$OUT/eval_${data}_${step}.json" "$data" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))
cells = [f"{r[k]['epe']:.3f} / {r[k]['bad3']:.2f}" for k in ("net", "net-nolidar")]
print(f"| {sys.argv[2]} | " + " | ".join(cells) + " |")
EOF
done
