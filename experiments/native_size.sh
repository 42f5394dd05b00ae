#!/bin/sh
# "fit", "budget" and "native" (`[engine] scale`) for the shipped bundle at three camera sizes:
# EPE / bad-3 against the ground truth and the median ms per pair (tools/evaluate.py, int8,
# the bundle's matching, 2 threads), on the rig world (16-beam LiDAR, 12 scenes) and the
# things world (scene folders, 12 scenes) rendered at each size from test-split seeds.
#     sh experiments/native_size.sh [OUT_DIR]   (default out/native_size)
set -e
BIN=${BIN:-.venv/bin}
OUT=${1:-out/native_size}
mkdir -p "$OUT"
grep -o -w 'avx512_vnni\|avx_vnni\|avx512_bf16' /proc/cpuinfo | sort -u | tr '\n' ' ' > "$OUT/isa.txt"
for size in 640x400 1280x800 1242x375; do
  for world in rig things; do
    data="data/native/$world-$size"
    if [ ! -d "$data" ]; then
      if [ $world = rig ]; then
        "$BIN/edge-depth" synth --out "$data" --count 12 --seed 1000000 --size $size --lidar beams16
      else
        "$BIN/edge-depth" synth --world things --scene-folders --out "$data" --count 12 \
          --seed 1100000 --size $size
      fi
    fi
    for scale in fit budget native; do
      "$BIN/python" tools/evaluate.py "$data" --methods net --scale $scale \
        --json "$OUT/$world-$size-$scale.json" > /dev/null
    done
  done
done
"$BIN/python" - "$OUT" <<'PY'
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
print(f"host ISA: {(out / 'isa.txt').read_text().strip() or 'AVX2 only'}")
scales = ("fit", "budget", "native")
print("| camera | world | " + " | ".join(f"{s} EPE / bad-3 | {s} ms" for s in scales) + " |")
print("|---|---|" + "---|---|" * len(scales))
for size in ("640x400", "1280x800", "1242x375"):
    for world in ("rig", "things"):
        r = {s: json.loads((out / f"{world}-{size}-{s}.json").read_text())["net"]
             for s in scales}
        print(f"| {size} | {world} | " + " | ".join(
            f"{r[s]['epe']:.3f} / {r[s]['bad3']:.2f} % | {r[s]['ms']:.0f}" for s in scales) + " |")
PY
