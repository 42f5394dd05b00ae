"""The band refinement followed by the grey-guided weighted median (`edge.runtime.edge_median`)
over the network's unsure edges: does the median that the defaults' matching ends with also
earn its keep after the band?

    python experiments/band_median.py runs/band/aloe runs/band/moto runs/band/test16/* \
        [--variants DIR/aloe_r14 ... --round 2] [--json OUT]

For each scene folder (and, with --variants, each of a band_judge round's four kinds on each
variant folder): the engine before the band ("shipped": `refine = "off"`, 4 GRU steps — the
edge matching and its median up to the tag stages-before-band, the median alone after it),
the engine with `refine = "band"` and its median off ("band"), and the band's output through
the 9x9/2 weighted median over a gate — "band+median": the unsure edges
(`edge_median.unsure_edges`: confidence under MAX_CONFIDENCE where the disparity's 5×5 range
exceeds MIN_RANGE_PX), "band+median(conf)": every pixel under that confidence.
Prints mean EPE px / bad-3 % per group (a real pair, the rig's split, each variant kind) and
the median's median time. `--iters N`: the band engine's GRU steps (the shipped engine keeps
the bundle's); `--stereo`: the folders' LiDAR zeroed (stereo only); `--band max_band:48`: the band's
constants (`band_sgm.BandSgmConfig`) other than its defaults.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import types
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from band_judge import ROUNDS, photo  # noqa: E402
from band_refine import parse_variant  # noqa: E402
from lidar_align_gate import variant  # noqa: E402

from edge_depth.metrics import disparity_metrics  # noqa: E402
from edge_depth.runtime import band_sgm  # noqa: E402
from edge_depth.runtime.edge_median import (  # noqa: E402
    MAX_CONFIDENCE,
    EdgeMedian,  # noqa: E402
    unsure_edges,
)
from edge_depth.runtime.engine import Engine  # noqa: E402
from edge_depth.runtime.options import EngineOptions  # noqa: E402
from edge_depth.sim.folder import read_scene_folder  # noqa: E402


def group_of(folder: Path) -> str:
    return folder.parent.name if folder.name.isdigit() else folder.name


def methods(engines: dict[str, Engine], median: EdgeMedian, left: np.ndarray,
            right: np.ndarray, sparse: np.ndarray, times: list[float],
            iters: int | None = None) -> dict[str, np.ndarray]:
    out = {"shipped": engines["shipped"].infer(left, right, sparse, iters=4).disparity}
    band = engines["band"].infer(left, right, sparse, iters=iters)
    out["band"] = band.disparity
    unsure = band.confidence < MAX_CONFIDENCE
    t = time.perf_counter()
    gate = unsure_edges(band.disparity, band.confidence)
    out["band+median"] = median.apply(band.disparity, left, gate)
    times.append((time.perf_counter() - t) * 1000)
    out["band+median(conf)"] = median.apply(band.disparity, left, unsure)
    return out


def cases(folders: list[Path], variants: list[Path], round_: int, stereo: bool = False):
    """(group, left, right, sparse, gt) for each folder (its LiDAR zeroed with `stereo`) and
    each variant's kinds."""
    for folder in folders:
        scene = read_scene_folder(folder)
        sparse = np.zeros_like(scene.sparse) if stereo else scene.sparse
        yield group_of(folder), scene.left, scene.right, sparse, scene.disp
    seed, kinds = ROUNDS[round_]
    for folder in variants:
        scene = read_scene_folder(folder)
        for name, (kind, change) in kinds.items():
            rng = np.random.default_rng(seed)
            sparse = variant(scene, kind, seed)
            right = scene.right if change is None else photo(scene.right, rng, change)
            yield f"{folder.name}/{name}", scene.left, right, sparse, scene.disp


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="*", type=Path)
    p.add_argument("--variants", nargs="*", type=Path, default=[])
    p.add_argument("--round", type=int, choices=sorted(ROUNDS), default=2)
    p.add_argument("--iters", type=int, help="the band engine's GRU steps (default: the "
                   "bundle's)")
    p.add_argument("--band", default="", help="BandSgmConfig fields for the band engine, "
                   "e.g. max_band:48")
    p.add_argument("--stereo", action="store_true", help="the folders' LiDAR zeroed")
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    engines = {"shipped": Engine(options=EngineOptions(runtime="onnxruntime", refine="off")),
               "band": Engine(options=EngineOptions(runtime="onnxruntime", refine="band",
                                                 edge_median="off"))}
    if args.band:
        config = parse_variant(f"x={args.band}")[1]
        engines["band"].band = types.SimpleNamespace(
            use_threads=band_sgm.use_threads,
            refine=lambda *a: band_sgm.refine(*a, config))  # the module with these constants
    median = EdgeMedian("9x9/2")
    rows: dict[str, dict[str, list]] = {}
    times: list[float] = []
    for group, left, right, sparse, gt in cases(args.folders, args.variants, args.round,
                                                      args.stereo):
        for method, disp in methods(engines, median, left, right, sparse, times,
                                           args.iters).items():
            m = disparity_metrics(disp, gt)
            rows.setdefault(group, {}).setdefault(method, []).append((m["epe"], m["bad3"]))
    summary = {g: {k: [float(np.mean([r[0] for r in v])), float(np.mean([r[1] for r in v]))]
                   for k, v in ms.items()} for g, ms in rows.items()}
    for group, ms in summary.items():
        print(group)
        for method, (epe, bad3) in ms.items():
            print(f"  {method:20s} {epe:.3f} / {bad3:.2f}")
    print(f"median ms (median): {np.median(times):.1f}")
    if args.json:
        args.json.write_text(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
