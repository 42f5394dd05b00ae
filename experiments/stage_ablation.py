"""Each stage after the network switched off alone, at the defaults (the band refinement and
its median) and, up to the tag stages-before-band, with `--refine off` (the edge matching in
the band's place; those stages are gone after it: run this there for them): what it earns on
the published pairs, the rig's test split and a round's variants of the pairs
(`band_judge.py`).

    python experiments/stage_ablation.py --pairs DIR/aloe DIR/moto --rig DIR/test16 \
        --variants DIR/aloe_r14 DIR/aloe_r48 DIR/moto_r14 DIR/moto_r48 [--round 2] \
        [--stereo] [--json OUT]

`--stereo`: the pairs and the rig with the LiDAR zeroed (the variants left out: without
LiDAR they are the pairs with the photometric change only). ONNX Runtime, int8. Prints mean
EPE px / bad-3 % per set and configuration, and each stage's cost when off relative to the
configuration with it on.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from band_judge import ROUNDS, photo  # noqa: E402
from lidar_align_gate import variant  # noqa: E402

from edge_depth.metrics import disparity_metrics  # noqa: E402
from edge_depth.runtime.engine import Engine  # noqa: E402
from edge_depth.runtime.options import EngineOptions  # noqa: E402
from edge_depth.sim.folder import read_scene_folder  # noqa: E402

# name -> the EngineOptions fields that switch the stage off
STAGES = {
    "LiDAR alignment": dict(align_lidar=False),
    "LiDAR selection": dict(lidar_select=False),
    "band refinement": dict(refine="off", edge_median="off"),
    "weighted median": dict(edge_median="off"),
}


def configurations() -> dict[str, dict]:
    configs = {"defaults": {}}
    configs.update({f"defaults − {k}": v for k, v in STAGES.items()})
    configs["refine off"] = dict(refine="off")  # the median alone after the network
    return configs


def inputs(args) -> dict[str, list]:
    """set name -> [(left, right, sparse, gt)]."""
    sets: dict[str, list] = {}
    for folder in args.pairs:
        s = read_scene_folder(folder)
        sets[folder.name] = [(s.left, s.right, s.sparse, s.disp)]
    rig = sorted(p for p in args.rig.iterdir() if p.is_dir())
    sets["rig"] = [(s.left, s.right, s.sparse, s.disp)
                   for s in map(read_scene_folder, rig)]
    seed, kinds = ROUNDS[args.round]
    sets["variants"] = []
    for folder in args.variants:
        s = read_scene_folder(folder)
        for kind, change in kinds.values():
            rng = np.random.default_rng(seed)
            sparse = variant(s, kind, seed)
            right = s.right if change is None else photo(s.right, rng, change)
            sets["variants"].append((s.left, right, sparse, s.disp))
    return sets


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pairs", nargs="+", type=Path, required=True)
    p.add_argument("--rig", type=Path, required=True)
    p.add_argument("--variants", nargs="+", type=Path, required=True)
    p.add_argument("--round", type=int, choices=sorted(ROUNDS), default=2,
                   help="the variants' kinds (band_judge.py's rounds)")
    p.add_argument("--stereo", action="store_true", help="every set with its LiDAR zeroed")
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    sets = inputs(args)
    if args.stereo:  # frames without points: where the edge selection and SGBM's case act
        sets = {k: [(a, b, np.zeros_like(c), d) for a, b, c, d in v]
                for k, v in sets.items() if k != "variants"}
    table: dict[str, dict[str, list[float]]] = {}
    for name, overrides in configurations().items():
        engine = Engine(options=EngineOptions(runtime="onnxruntime", precision="int8",
                                              **overrides))
        for set_name, items in sets.items():
            scores = [disparity_metrics(engine.infer(left, right, sparse).disparity, gt)
                      for left, right, sparse, gt in items]
            table.setdefault(name, {})[set_name] = [
                float(np.mean([m["epe"] for m in scores])),
                float(np.mean([m["bad3"] for m in scores]))]
        print(name, json.dumps(table[name]), flush=True)
    names = list(sets)
    print("| configuration | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for name, row in table.items():
        base = table["refine off" if name.startswith("refine off") else "defaults"]
        cells = []
        for n in names:
            epe, bad3 = row[n]
            if name in ("defaults", "refine off"):
                cells.append(f"{epe:.3f} / {bad3:.2f}")
            else:
                cells.append(f"{epe:.3f} / {bad3:.2f} ({epe / base[n][0] - 1:+.1%}, "
                             f"{bad3 - base[n][1]:+.2f})")
        print(f"| {name} | " + " | ".join(cells) + " |")
    if args.json:
        args.json.write_text(json.dumps(table, indent=1))


if __name__ == "__main__":
    main()
