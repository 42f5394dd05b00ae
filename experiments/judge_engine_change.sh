#!/usr/bin/env bash
# A change to the engine's code (not to a bundle) judged by the shipped bundle's accuracy:
# the real pairs (16 and 8 LiDAR rows, stereo only), the rig's test split and the eight
# real-pair variants, int8 at 4 iterations, on each path the bars hold for: OpenVINO with an
# AVX2-only CPU's kernels (experiments/avx2_kernels.sh: what `auto` runs there), OpenVINO
# with this host's own kernels (what `auto` runs on a VNNI host) and ONNX Runtime (ARM, and
# the README's accuracy commands). Run it on the reference commit, then with the change, the
# second time with REFERENCE= the first run's folder for the tables:
#     bash experiments/judge_engine_change.sh runs/judge_ref
#     REFERENCE=runs/judge_ref bash experiments/judge_engine_change.sh runs/judge_change
# PATHS="avx2 native ort": the paths to run (default all three); FLAGS="…": more evaluate
# flags (e.g. an engine option off, for a reference run on the same commit); MORE="…": more
# data folders after the standard ones; ONLY="…": these folders instead of all the others.
set -euo pipefail
OUT=$1
BIN=${BIN:-.venv/bin}
PATHS=${PATHS:-avx2 native ort}
[ -d data/aloe ] || "$BIN/python" tools/real_pairs.py
[ -d data/motorcycle ] || "$BIN/python" tools/real_pairs.py --motorcycle
[ -d data/aloe_r8 ] || "$BIN/python" tools/real_pairs.py --rows 8 --out data/aloe_r8
[ -d data/motorcycle_r8 ] || "$BIN/python" tools/real_pairs.py --motorcycle --rows 8 --out data/motorcycle_r8
[ -d data/test16 ] || "$BIN/edge-depth" synth --out data/test16 --count 20 --seed 1000000 --lidar beams16
[ -d data/variants/aloe_noise ] || "$BIN/python" experiments/pair_variants.py data/aloe data/motorcycle --out data/variants
[ -d data/photo_variants/aloe_gain09 ] || "$BIN/python" experiments/photometric_variants.py data/aloe data/motorcycle --out data/photo_variants
[ -d data/misregistered/aloe_left2 ] || "$BIN/python" experiments/lidar_misregistration.py data/aloe data/motorcycle --out data/misregistered
[ -d data/photo_strong/aloe_gain075 ] || "$BIN/python" experiments/photometric_variants.py data/aloe data/motorcycle --strong --out data/photo_strong
[ -d data/noisy/aloe_n040 ] || "$BIN/python" experiments/lidar_noise.py data/aloe data/motorcycle --out data/noisy
DATA="data/aloe data/motorcycle data/aloe_r8 data/motorcycle_r8 data/test16 $(ls -d data/variants/* data/photo_variants/* data/misregistered/* data/noisy/* data/photo_strong/* | tr '\n' ' ')${MORE:-}"
[ -z "${ONLY:-}" ] || DATA=$ONLY
mkdir -p "$OUT"
echo "host: $(grep -o -w 'avx2\|avx512f\|avx512_vnni\|avx_vnni\|avx512_bf16' /proc/cpuinfo | sort -u | tr '\n' ' ')($(nproc) cores); paths $PATHS; commit $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- edge || echo ' + uncommitted changes to edge/')"
for path in $PATHS; do
  case $path in
    avx2) run=(bash experiments/avx2_kernels.sh "$BIN/python"); flags=(--runtime openvino --bf16 off) ;;
    native) run=("$BIN/python"); flags=(--runtime openvino) ;;
    ort) run=("$BIN/python"); flags=(--runtime onnxruntime) ;;
    *) echo "unknown path $path (avx2, native or ort)" >&2; exit 2 ;;
  esac
  for data in $DATA; do
    "${run[@]}" tools/evaluate.py "$data" --methods net --no-lidar "${flags[@]}" \
      --precision int8 --iters 4 ${FLAGS:-} --json "$OUT/eval_${path}_$(basename "$data").json" > /dev/null
  done
done
[ -n "${REFERENCE:-}" ] || exit 0
"$BIN/python" - "$REFERENCE" "$OUT" "$PATHS" $DATA <<'PY'
import json, sys
from pathlib import Path
reference, out, paths = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3].split()
for path in paths:
    print(f"\n{path}:\n")
    print("| data | reference EPE / bad-3 | stereo only | change EPE / bad-3 | stereo only | EPE change |")
    print("|---|---|---|---|---|---|")
    for data in map(lambda d: Path(d).name, sys.argv[4:]):
        cells, epe = [], []
        for folder in (reference, out):
            r = json.loads((folder / f"eval_{path}_{data}.json").read_text())
            epe.append(r["net"]["epe"])
            for key in ("net", "net-nolidar"):
                cells.append(f"{r[key]['epe']:.3f} / {r[key]['bad3']:.2f}" if key in r else "—")
        print(f"| {data} | " + " | ".join(cells) + f" | {100 * (epe[1] / epe[0] - 1):+.1f} % |")
PY
