#!/usr/bin/env bash
# The shipped bundle against a copy whose encoder runs in int8 (experiments/encoder_int8.py), on
# the real pairs (16 and 8 LiDAR rows, stereo only) and the rig's test split, int8 at 4
# iterations; by default on OpenVINO with an AVX2-only CPU's kernels (experiments/avx2_kernels.sh):
# what `auto` runs there.
#     bash experiments/judge_encoder_int8.sh runs/enc8 runs/judge_enc8
# KERNELS=native: this host's own kernels; RUNTIME=onnxruntime; BF16=auto|on|off (default off);
# DATA="data/variants/aloe_noise ...": other scene folders (default the real pairs and data/test16);
# ROWS=1: the candidate's matching on every row (the shipped bundle keeps its own).
set -euo pipefail
CANDIDATE=$1
OUT=$2
BIN=${BIN:-.venv/bin}
KERNELS=${KERNELS:-avx2}
RUNTIME=${RUNTIME:-openvino}
BF16=${BF16:-off}
DATA=${DATA:-data/aloe data/motorcycle data/aloe_r8 data/motorcycle_r8 data/test16}
ROWS=${ROWS:-bundle}
WRAP=()
[ "$KERNELS" = avx2 ] && WRAP=(bash experiments/avx2_kernels.sh)
mkdir -p "$OUT"
echo "host: $(grep -o -w 'avx2\|avx512f\|avx512_vnni\|avx_vnni\|avx512_bf16' /proc/cpuinfo | sort -u | tr '\n' ' ')($(nproc) cores); kernels $KERNELS, $RUNTIME, bf16 $BF16, the candidate's rows $ROWS"
for data in $DATA; do
  for model in edge/models/default "$CANDIDATE"; do
    rows=bundle
    [ "$model" = "$CANDIDATE" ] && rows=$ROWS
    "${WRAP[@]}" "$BIN/python" tools/evaluate.py "$data" --model "$model" --methods net \
      --no-lidar --runtime "$RUNTIME" --precision int8 --bf16 "$BF16" --iters 4 \
      --edge-match-rows "$rows" --json "$OUT/eval_$(basename "$data")_$(basename "$model").json" \
      > /dev/null
  done
done
"$BIN/python" - "$OUT" "$(basename "$CANDIDATE")" $DATA <<'PY'
import json, sys
from pathlib import Path
out, candidate = Path(sys.argv[1]), sys.argv[2]
print("| data | shipped EPE / bad-3 | stereo only | candidate EPE / bad-3 | stereo only | EPE change |")
print("|---|---|---|---|---|---|")
for data in map(lambda d: Path(d).name, sys.argv[3:]):
    cells, epe = [], []
    for tag in ("default", candidate):
        r = json.loads((out / f"eval_{data}_{tag}.json").read_text())
        epe.append(r["net"]["epe"])
        for key in ("net", "net-nolidar"):
            cells.append(f"{r[key]['epe']:.3f} / {r[key]['bad3']:.2f}" if key in r else "—")
    print(f"| {data} | " + " | ".join(cells) + f" | {100 * (epe[1] / epe[0] - 1):+.1f} % |")
PY
