"""The band refinement's constants as shipped against one change of them, on variants of the
real pairs, with the LiDAR and stereo only (docs/experiments.md, 2026-12-07 22:43).

    python tools/real_pairs.py --rows R --out DIR/aloe_rR; python tools/real_pairs.py
        --motorcycle --rows R --out DIR/moto_rR   (R = 12, 28)
    python experiments/band_config_judge.py DIR/aloe_r12 DIR/aloe_r28 DIR/moto_r12
        DIR/moto_r28 --set KEY=VALUE ... [--rig data/test16]

(`--set min_change=0` at 22:44, before that field went by its result.)

Each folder × KINDS is one set (the map from `lidar_align_gate.variant`, the right camera from
`band_judge.photo`, seed SEED), and stereo only (the LiDAR zeroed) with the right camera as it
is and with PHOTO's change; the engine at its defaults (ONNX Runtime) runs each set with the
band's constants as shipped ("shipped") and with `--set`'s ("changed"), and the worst set's
change is printed last.
"""

from __future__ import annotations

import argparse
import json
import sys
import types
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from band_judge import photo, score  # noqa: E402
from lidar_align_gate import variant  # noqa: E402

from edge_depth.runtime import band_sgm  # noqa: E402
from edge_depth.runtime.engine import Engine  # noqa: E402
from edge_depth.runtime.options import EngineOptions  # noqa: E402
from edge_depth.sim.folder import read_scene_folder  # noqa: E402

SEED = 50321
PHOTO = (1.1, -8.0, 0.9, 2.0)
KINDS = {  # (σ px, mixed share, mixed reach px, drop share, turn °, dx, dy), photo change
    "noisy": ((0.6, 0.35, 3, 0.0, 0.0, 0, 0), None),
    "moved": ((0.0, 0.0, 0, 0.0, 0.25, -2, 1), None),
    "photo": ((0.0, 0.0, 0, 0.0, 0.0, 0, 0), PHOTO),
    "all": ((0.4, 0.25, 3, 0.25, 0.0, 1, -2), PHOTO),
    "stereo": (None, None),
    "stereo photo": (None, PHOTO),
}


def parsed(items: list[str]) -> dict:
    """KEY=VALUE pairs as BandSgmConfig fields, each of its field's type."""
    shipped = band_sgm.BandSgmConfig()
    return {k: type(getattr(shipped, k))(v) for k, v in (i.split("=", 1) for i in items)}


def refine_with(engine: Engine, config: band_sgm.BandSgmConfig) -> None:
    """The engine's band refinement with `config`'s constants from now on."""
    engine.band = types.SimpleNamespace(  # type: ignore[assignment]
        use_threads=band_sgm.use_threads, refine=lambda *a: band_sgm.refine(*a, config))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="*", type=Path)
    p.add_argument("--set", nargs="+", required=True, metavar="KEY=VALUE")
    p.add_argument("--rig", type=Path, help="also the mean over this folder's scene folders "
                   "(the rig's test split: data/test16) with its own LiDAR")
    args = p.parse_args()
    engine = Engine(options=EngineOptions(runtime="onnxruntime"))
    configs = {"shipped": band_sgm.BandSgmConfig(),
               "changed": replace(band_sgm.BandSgmConfig(), **parsed(args.set))}
    worst_epe, worst_bad3 = -np.inf, -np.inf
    for folder in args.folders:
        scene = read_scene_folder(folder)
        for name, (kind, change) in KINDS.items():
            sparse = np.zeros_like(scene.sparse) if kind is None else \
                variant(scene, kind, SEED)
            right = scene.right if change is None else \
                photo(scene.right, np.random.default_rng(SEED), change)
            row = {"set": f"{folder.name}/{name}"}
            for label, config in configs.items():
                refine_with(engine, config)
                row[label] = score(engine.infer(scene.left, right, sparse).disparity,
                                   scene.disp)
            worst_epe = max(worst_epe, row["changed"][0] / row["shipped"][0] - 1)
            worst_bad3 = max(worst_bad3, row["changed"][1] - row["shipped"][1])
            print(json.dumps(row), flush=True)
    if args.rig:
        scenes = [read_scene_folder(f) for f in sorted(args.rig.iterdir()) if f.is_dir()]
        for label, config in configs.items():
            refine_with(engine, config)
            rows = [score(engine.infer(s.left, s.right, s.sparse).disparity, s.disp)
                    for s in scenes]
            print(f"{args.rig} ({len(rows)} scenes), {label}: EPE {np.mean(rows, axis=0)[0]:.3f}"
                  f" px, bad-3 {np.mean(rows, axis=0)[1]:.2f} %")
    print(f"{' '.join(args.set)} against shipped: worst EPE {worst_epe:+.2%}, worst bad-3 "
          f"{worst_bad3:+.3f} points")


if __name__ == "__main__":
    main()
