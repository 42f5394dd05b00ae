"""The band refinement (`edge.runtime.band_sgm`) against the shipped engine's stages.

    python experiments/band_refine.py runs/band/aloe runs/band/moto runs/band/test16/* \
        [--variant NAME=min_band,max_band ...] [--json OUT]

For each scene folder: the shipped engine at its defaults ("shipped"); the network with every
stage after it off ("prior": LiDAR and edge selection, the matching, the median); and the
prior refined by the band SGM for each variant ("band:NAME"); with --no-lidar the same with the
LiDAR zeroed (stereo only). Prints mean EPE px / bad-3 % per group of folders (a group: the
folders' common parent for the synthetic split, each real pair its own) and the median time of
the refinement and of SGBM (64 disparities) on the same pairs.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from edge_depth.baselines import make_sgbm, sgbm_disparity
from edge_depth.metrics import disparity_metrics
from edge_depth.runtime.band_sgm import BandSgmConfig, refine
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.options import EngineOptions
from edge_depth.sim.folder import read_scene_folder

PRIORS = dict(bare=dict(lidar_select=False, edge_select=False, edge_match=0, edge_median="off"),
              selected=dict(edge_match=0, edge_median="off"))


def group_of(folder: Path) -> str:
    return folder.parent.name if folder.name.isdigit() else folder.name


def run(folders: list[Path], variants: dict[str, BandSgmConfig], no_lidar: bool,
        runtime: str, prior_stages: str) -> dict:
    shipped = Engine(options=EngineOptions(runtime=runtime))
    bare = Engine(options=EngineOptions(runtime=runtime, **PRIORS[prior_stages]))
    sgbm = make_sgbm(64)  # the time the engine's is judged against (tools/bench.py's)
    rows: dict[str, dict[str, list]] = {}
    times: dict[str, list[float]] = {}
    modes = [("lidar", False)] + ([("stereo", True)] if no_lidar else [])
    for folder in folders:
        scene = read_scene_folder(folder)
        group = group_of(folder)
        for mode, zeroed in modes:
            sparse = np.zeros_like(scene.sparse) if zeroed else scene.sparse
            results = {"shipped": shipped.infer(scene.left, scene.right, sparse).disparity}
            prior = bare.infer(scene.left, scene.right, sparse)
            results["prior"] = prior.disparity
            for name, config in variants.items():
                t = time.perf_counter()
                results[f"band:{name}"], _ = refine(scene.left, scene.right, prior.disparity,
                                                    prior.confidence, sparse, config)
                times.setdefault(name, []).append((time.perf_counter() - t) * 1000)
            t = time.perf_counter()
            sgbm_disparity(scene.left, scene.right, sgbm)
            times.setdefault("SGBM 64", []).append((time.perf_counter() - t) * 1000)
            for method, disp in results.items():
                m = disparity_metrics(disp, scene.disp)
                key = f"{group}/{mode}"
                rows.setdefault(key, {}).setdefault(method, []).append(
                    (m["epe"], m["bad3"]))
    summary = {key: {method: [float(np.mean([r[0] for r in v])),
                              float(np.mean([r[1] for r in v]))]
                     for method, v in methods.items()} for key, methods in rows.items()}
    return dict(summary=summary, ms={k: float(np.median(v)) for k, v in times.items()})


def parse_variant(text: str) -> tuple[str, BandSgmConfig]:
    name, _, values = text.partition("=")
    fields = dict(kv.split(":") for kv in values.split(",") if kv)
    ints = {"min_band", "max_band", "p1", "p2", "median", "uniqueness", "paths",
            "choose_fallback", "refine_margin_px"}
    return name, BandSgmConfig(**{k: int(v) if k in ints else float(v)
                                  for k, v in fields.items()})


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--variant", action="append", default=[],
                   help="NAME=min_band:2,max_band:4 (BandSgmConfig fields)")
    p.add_argument("--no-lidar", action="store_true")
    p.add_argument("--runtime", default="onnxruntime")
    p.add_argument("--prior", choices=sorted(PRIORS), default="selected")
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    variants = dict(parse_variant(v) for v in args.variant) or {"default": BandSgmConfig()}
    result = run(args.folders, variants, args.no_lidar, args.runtime, args.prior)
    for key, methods in result["summary"].items():
        print(key)
        for method, (epe, bad3) in methods.items():
            print(f"  {method:24s} {epe:.3f} / {bad3:.2f}")
    print("ms (median):", {k: round(v, 1) for k, v in result["ms"].items()})
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
