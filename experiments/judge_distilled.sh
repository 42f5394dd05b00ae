#!/usr/bin/env bash
# A lighter network trained by distillation (tools/train.py --teacher) judged by the rule of
# its run (docs/experiments.md, "run distil12"): made into a bundle as `make bundle` makes one,
# selections fitted (experiments/judge_candidate.sh, accuracy at 4 iterations on ONNX
# Runtime), given its int8 encoder (experiments/encoder_int8.py), then, with AVX2 kernels on
# OpenVINO (what `auto` runs on an AVX2-only CPU), the real pairs, their 8-row and stereo-only
# versions, the test split and the eight real-pair variants at the matching's two row steps,
# and its engine against the shipped one alternated frame by frame.
#     bash experiments/judge_distilled.sh runs/distil12/final.pt runs/judge_distil12
set -euo pipefail
CKPT=$1
OUT=$2
BIN=${BIN:-.venv/bin}
JUDGE_ITERS=4 SPEED=0 bash experiments/judge_candidate.sh "$CKPT" "$OUT" fit
"$BIN/python" experiments/encoder_int8.py "$OUT/bundle" "$OUT/enc8"
[ -d data/variants/aloe_noise ] || "$BIN/python" experiments/pair_variants.py data/aloe data/motorcycle --out data/variants
VARIANTS=$(ls -d data/variants/* | tr '\n' ' ')
for rows in bundle 1; do
  echo "== the candidate's matching rows: $rows"
  ROWS=$rows bash experiments/judge_encoder_int8.sh "$OUT/enc8" "$OUT/avx2_rows_$rows"
  ROWS=$rows DATA="$VARIANTS" bash experiments/judge_encoder_int8.sh "$OUT/enc8" \
    "$OUT/avx2_variants_rows_$rows"
done
bash experiments/avx2_kernels.sh "$BIN/python" experiments/bundle_engine_ab.py \
  edge/models/default "$OUT/enc8" --edge-match-rows bundle,1 --frames 40
