"""The band refinement's time by part, on the inputs the engine gives it (docs/experiments.md).

    python experiments/band_parts.py data/aloe data/motorcycle data/test16/100000[0-3] \
        [--rounds 5] [--dump runs/band_inputs.npz]
    bash experiments/avx2_kernels.sh .venv/bin/python experiments/band_parts.py ...

The engine at its defaults runs each pair once; the band's inputs (the staged pair, the
selected disparity, its confidence, the LiDAR map) are kept and `band_sgm.refine` runs on them
again, part by part, `--rounds` times after an untimed call. Per part: the median over rounds
of the summed time over the pairs. With `--load`, inputs dumped before by `--dump` (no engine).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from edge_depth.runtime import band_sgm as bs


def capture(folders: list[Path]) -> list[dict[str, np.ndarray]]:
    """The band's inputs from one engine run per pair."""
    from edge_depth.runtime.engine import Engine
    from edge_depth.runtime.options import EngineOptions
    from edge_depth.sim.folder import read_scene_folder

    engine = Engine(options=EngineOptions())
    kept: list[dict[str, np.ndarray]] = []
    real = engine.band.refine

    def keep(left, right, prior, confidence, sparse, config=None):
        kept.append(dict(left=np.array(left), right=np.array(right), prior=np.array(prior),
                         confidence=np.array(confidence), sparse=np.array(sparse)))
        return real(left, right, prior, confidence, sparse, config)

    engine.band.refine = keep
    try:
        for folder in folders:
            s = read_scene_folder(folder)
            engine.infer(s.left, s.right, s.sparse)
    finally:
        engine.band.refine = real
    return kept


def parts(x: dict[str, np.ndarray], config: bs.BandSgmConfig) -> dict[str, float]:
    """`band_sgm.refine`'s parts, each timed (ms), and the volume's size."""
    times: dict[str, float] = {}
    _, _ = bs.refine(x["left"], x["right"], x["prior"], x["confidence"], x["sparse"], config,
                     parts_ms=times)
    return times


def volume(x: dict[str, np.ndarray], config: bs.BandSgmConfig) -> tuple[float, float]:
    """The ragged volume's labels (millions) and the refined share of the pixels (%)."""
    sparse = x["sparse"]
    points = np.where(np.isfinite(sparse) & (sparse > 0), sparse, 0.0).astype(np.float32)
    _, count, start, _ = bs._bands(np.nan_to_num(x["prior"]).astype(np.float32),
                                   np.nan_to_num(x["confidence"]).astype(np.float32), points,
                                   config)
    return float(start[-1]) / 1e6, 100.0 * np.count_nonzero(count) / count.size


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="*", type=Path)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--dump", type=Path)
    p.add_argument("--load", type=Path)
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                   help="BandSgmConfig fields other than the defaults, e.g. max_band=32")
    args = p.parse_args()
    cv2.setNumThreads(2)
    bs.use_threads(2)
    if args.load:
        with np.load(args.load) as z:
            n = int(z["n"])
            inputs = [{k: z[f"{i}_{k}"] for k in ("left", "right", "prior", "confidence",
                                                  "sparse")} for i in range(n)]
    else:
        inputs = capture(args.folders)
    if args.dump:
        args.dump.parent.mkdir(parents=True, exist_ok=True)
        np.savez(args.dump, n=len(inputs),
                 **{f"{i}_{k}": v for i, x in enumerate(inputs) for k, v in x.items()})
    fields = {k: type(getattr(bs.BandSgmConfig, k))(v)
              for k, v in (item.split("=", 1) for item in args.set)}
    config = bs.BandSgmConfig(**fields)
    for x in inputs:
        parts(x, config)  # untimed
    rounds = []
    for _ in range(args.rounds):
        total: dict[str, float] = {}
        for x in inputs:
            for name, ms in parts(x, config).items():
                total[name] = total.get(name, 0.0) + ms
        rounds.append(total)
    n = len(inputs)
    print(f"{n} pairs, {args.rounds} rounds; per pair (median over rounds):")
    whole = 0.0
    for name in rounds[0]:
        value = float(np.median([r[name] for r in rounds])) / n
        whole += value
        print(f"  {name:10s} {value:7.2f}")
    print(f"  {'all':10s} {whole:7.2f} ms")
    labels, refined = np.mean([volume(x, config) for x in inputs], axis=0)
    print(f"  {labels:.2f} M labels, {refined:.1f} % of the pixels refined")


if __name__ == "__main__":
    main()
