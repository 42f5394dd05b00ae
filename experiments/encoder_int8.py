"""A bundle's int8 encoder (model.json's "int8_encoder") made as `tools/quantize.py` makes it
(its stem float, calibrated on the rig's scenes), without choosing its other
graphs again: into a copy of the bundle (OUT) for timing and judging against the original
(`experiments/bundle_engine_ab.py BUNDLE OUT`, `experiments/judge_encoder_int8.sh OUT DIR`), or
into the bundle itself (`--in-place`).

    python experiments/encoder_int8.py edge/models/default runs/enc8 [--calib data/calib_mix]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))

from quantize import ENCODER_CALIB, GraphChoices, calibration_frames, int8_encoder  # noqa: E402

from edge_depth.runtime.backends import resolve_runtime  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("bundle", type=Path)
    p.add_argument("out", type=Path, nargs="?")
    p.add_argument("--in-place", action="store_true")
    p.add_argument("--calib", default=ENCODER_CALIB, help="the encoder's calibration frames")
    args = p.parse_args()
    if args.in_place == (args.out is not None):
        p.error("either OUT or --in-place")
    bundle = args.bundle
    if args.out is not None:
        if args.out.exists():
            shutil.rmtree(args.out)
        shutil.copytree(bundle, args.out)
        bundle = args.out
    meta = json.loads((bundle / "model.json").read_text())
    meta.pop("int8_encoder", None)
    q = meta["quantization"]
    run = GraphChoices(bundle, meta, [], q["iters"], 2, resolve_runtime("auto"),
                       q["max_graph_px"], q["max_total_px"], q["max_confidence"],
                       q["min_gain"], False)
    run.frames = list(calibration_frames(q["calibration"], run.fp32.size))  # the agreement's
    entry = int8_encoder(run, args.calib)
    if entry is None:
        raise SystemExit(f"{bundle}: the int8 encoder moves the disparity beyond "
                         f"{q['max_graph_px']} px; none written")
    meta["int8_encoder"] = entry
    (bundle / "model.json").write_text(json.dumps(meta, indent=2))
    print(f"{bundle}: int8_encoder = {meta['int8_encoder']}")


if __name__ == "__main__":
    main()
