"""Fit the stereo-only edge selection (`edge.runtime.edge_select`) on a bundle's own outputs
and store it in the bundle's model.json.

    python tools/fit_edge_select.py BUNDLE --data data/things_select [--frames 300]
        [--rig-share 0.4] [--holdout 0.25] [--side-cells 3] [--max-confidence 0.9]
        [--min-margin 0]
        [--confirm DIR [--confirm-frames 250] [--confirm-seed 1]] [--dry-run]

The frames are `tools/fit_select.py`'s (things samples no shipped stage trained on, and a
share of rig frames from training seeds) with the LiDAR left out: the stage runs only on
frames without points. The bundle runs on each (int8, its default iterations); at each 2×2
cell where the network is not confident and its near and far sides differ, the three
candidates' summed errors over the cell's known pixels are kept, and the scorer learns per
side whether it is nearer the truth than the network, weighted by how much (each pixel's
error capped at MAX_ERROR_PX, so that a few wild cells do not decide the fit). A held-out
share of the frames reports what the fitted choice does to EPE and bad-3, per source (rig /
things); with `--confirm`, so do frames from another folder and seed that the fit never
saw. Last, the confidence of the pixels it replaces is fitted: sigmoid(a · margin + b) as
the share within 1 px (held-out: predicted vs measured).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from edge_depth.runtime.cells import CELL_PX
from edge_depth.runtime.edge_select import (
    CANDIDATES,
    SIDE_CELLS,
    EdgeSelect,
    edge_features,
    sides_apart,
)
from edge_depth.runtime.engine import Engine
from edge_depth.tools.fit_select import (
    MAX_WEIGHT_PX,
    add_fit_arguments,
    calibrate,
    candidate_gains,
    candidate_row,
    fit_perceptron,
    fitting_engine,
    frames,
    report,
    score,
    store,
)


def frame_row(source: str, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
              confidence: np.ndarray, gt: np.ndarray, side_cells: int,
              max_confidence: float) -> dict:
    """One frame's candidate cells (`edge_features`) as `candidate_row` scores them."""
    features, cells, values = edge_features(left, right, disparity, confidence, side_cells,
                                            max_confidence)
    return candidate_row(source, features, cells, values, disparity, gt)


def collect(engine: Engine, data: Path, count: int, rig_share: float, seed: int,
            side_cells: int, max_confidence: float) -> list[dict]:
    """`frame_row` for each of `frames`, stereo only (progress on stderr)."""
    out = []
    start = time.perf_counter()
    for i, (source, left, right, _, gt) in enumerate(frames(data, count, rig_share,
                                                            engine.size, seed)):
        result = engine.infer(left, right, np.zeros(left.shape, np.float32))
        out.append(frame_row(source, left, right, result.disparity, result.confidence, gt,
                             side_cells, max_confidence))
        if (i + 1) % 20 == 0 or i + 1 == count:
            print(f"fit_edge_select: {i + 1}/{count} frames "
                  f"({time.perf_counter() - start:.0f} s)", file=sys.stderr, flush=True)
    return out


def fit(rows: list[dict], hidden: int, steps: int, seed: int, side_cells: int,
        max_confidence: float, min_margin: float = 0.0) -> EdgeSelect:
    """Two weighted logistic losses on one hidden ReLU layer (`fit_perceptron`): per side,
    whether it is nearer the truth than the network over the cell, weighted by how much
    (capped): `tools/fit_select.py`'s recipe, once per side. The network's logit is
    fixed at 0, so a side is taken where its logit is positive and the other side's lower.
    min_margin: the sides' logits are lowered by it (a side is taken only where the fit is
    that sure; chosen on held-out frames). (Minimising the softmax choice's expected error
    directly settled on never switching.)"""
    x, gain = candidate_gains(rows, blend=0.0)  # (N, 2): how much nearer each side is
    # a side equal to the network's value is never chosen (EdgeSelect.choose): no loss there
    weight = np.minimum(np.abs(gain), MAX_WEIGHT_PX * CELL_PX * CELL_PX) * sides_apart(x)
    mean, std, w1, b1, sides_w, sides_b = fit_perceptron(x, gain > 0, weight, hidden, steps,
                                                         seed, per_weight=True)
    w2 = np.zeros((hidden, len(CANDIDATES)), np.float32)
    w2[:, 1:] = sides_w
    b2 = np.zeros(len(CANDIDATES), np.float32)
    b2[1:] = sides_b - min_margin  # a side must win by min_margin
    return EdgeSelect(mean=mean, std=std, w1=w1, b1=b1, w2=w2, b2=b2, side_cells=side_cells,
                      max_confidence=max_confidence)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_fit_arguments(p)
    # defaults: the variant the held-out frames chose on stage 15's bundle
    # (docs/experiments.md)
    p.add_argument("--side-cells", type=int, default=SIDE_CELLS,
                   help="the near / far sides: max / min over this many cells square (odd)")
    p.add_argument("--min-margin", type=float, default=0.0,
                   help="a side is taken only where its logit is at least this")
    args = p.parse_args(argv)
    if args.side_cells < 3 or args.side_cells % 2 == 0:
        raise SystemExit("--side-cells: an odd number ≥ 3")
    engine = fitting_engine(args)
    gate = args.max_confidence or np.inf
    rows = collect(engine, args.data, args.frames, args.rig_share, args.seed, args.side_cells,
                   gate)
    n_hold = max(1, int(round(len(rows) * args.holdout)))
    fit_rows, hold_rows = rows[n_hold:], rows[:n_hold]
    select = fit(fit_rows, args.hidden, args.steps, args.seed, args.side_cells, gate,
                 args.min_margin)
    heldout = report("held-out (stereo only)", hold_rows, score, select)
    calibrate(select, fit_rows, hold_rows, heldout)
    select = calibrate(fit(rows, args.hidden, args.steps, args.seed, args.side_cells, gate,
                           args.min_margin), rows, [], {})  # stored: fitted on every frame
    confirmed = None
    if args.confirm is not None:
        confirm_rows = collect(engine, args.confirm, args.confirm_frames, args.rig_share,
                               args.confirm_seed, args.side_cells, gate)
        confirmed = report("confirmation (stereo only)", confirm_rows, score, select)
    if args.dry_run:
        return 0
    store(args.bundle, "edge_select", dict(select.to_meta(), frames=args.frames,
                                           data=str(args.data), rig_share=args.rig_share,
                                           seed=args.seed, min_margin=args.min_margin,
                                           heldout=heldout, confirmation=confirmed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
