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
from dataclasses import replace
from pathlib import Path

import numpy as np

from edge_depth.runtime.edge_select import (
    CANDIDATES,
    SIDE_CELLS,
    EdgeSelect,
    edge_features,
    sides_apart,
)
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.lidar_select import CELL_PX
from edge_depth.tools.fit_select import (
    add_fit_arguments,
    fit_perceptron,
    frames,
    known_cell_pixels,
    logistic_share,
    report,
    store,
)

MAX_ERROR_PX = 16.0  # a pixel's error, capped, in the fit's gains
MAX_WEIGHT_PX = 8.0  # a pixel's share of its cell's weight (how much nearer), capped


def frame_row(source: str, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
              confidence: np.ndarray, gt: np.ndarray, side_cells: int,
              max_confidence: float) -> dict:
    """One frame's candidate cells: features, per candidate the summed error, bad-3 count and
    pixels within 1 px over the cell's known pixels, and the frame's own totals."""
    features, cells, values = edge_features(left, right, disparity, confidence, side_cells,
                                            max_confidence)
    gt, known, err_net, pixels, owner = known_cell_pixels(cells, disparity, gt)
    errors = [err_net[pixels]] + [np.abs(values[owner, i] - gt[pixels]) for i in (0, 1)]

    def per_cell(weights: np.ndarray) -> np.ndarray:
        return np.bincount(owner, weights, minlength=len(cells))

    return dict(source=source, features=features,
                err=np.stack([per_cell(e) for e in errors], 1),
                capped=np.stack([per_cell(np.minimum(e, MAX_ERROR_PX)) for e in errors], 1),
                bad3=np.stack([per_cell((e > 3).astype(np.float64)) for e in errors], 1),
                within1=np.stack([per_cell((e < 1).astype(np.float64)) for e in errors], 1),
                pixels=np.bincount(owner, minlength=len(cells)),
                known=int(known.sum()), err_sum=float(err_net[known].sum()),
                bad3_sum=int((err_net[known] > 3).sum()))


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
    x = np.concatenate([r["features"] for r in rows])
    cost = np.concatenate([r["capped"] for r in rows])
    gain = cost[:, :1] - cost[:, 1:]  # (N, 2): how much nearer each side is
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


def score(rows: list[dict], select: EdgeSelect | None) -> tuple[float, float]:
    """Mean EPE and bad-3 % over the frames' known pixels, with or without the choice."""
    epe, bad3 = [], []
    for r in rows:
        err_sum, bad = r["err_sum"], float(r["bad3_sum"])
        if select is not None and len(r["features"]):
            choice, _ = select.choose(r["features"])
            cells = np.arange(len(choice))
            err_sum -= float((r["err"][:, 0] - r["err"][cells, choice]).sum())
            bad -= float((r["bad3"][:, 0] - r["bad3"][cells, choice]).sum())
        epe.append(err_sum / max(r["known"], 1))
        bad3.append(100.0 * bad / max(r["known"], 1))
    return float(np.mean(epe)), float(np.mean(bad3))


def replaced_cells(rows: list[dict], select: EdgeSelect) -> tuple[np.ndarray, np.ndarray,
                                                                 np.ndarray]:
    """Over the cells the choice replaces: (margins, known pixels, of those within 1 px)."""
    margins, pixels, within1 = [], [], []
    for r in rows:
        if len(r["features"]):
            choice, margin = select.choose(r["features"])
            take = (choice > 0) & (r["pixels"] > 0)
            margins.append(margin[take])
            pixels.append(r["pixels"][take])
            within1.append(r["within1"][take, choice[take]])
    if not margins:
        return np.zeros(0, np.float32), np.zeros(0), np.zeros(0)
    return np.concatenate(margins), np.concatenate(pixels), np.concatenate(within1)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_fit_arguments(p)
    # defaults: the variant the held-out frames chose on stage 15's bundle
    # (docs/experiments.md, session 21)
    p.add_argument("--side-cells", type=int, default=SIDE_CELLS,
                   help="the near / far sides: max / min over this many cells square (odd)")
    p.add_argument("--min-margin", type=float, default=0.0,
                   help="a side is taken only where its logit is at least this")
    p.add_argument("--confirm", type=Path, help="also score on frames from this folder")
    p.add_argument("--confirm-frames", type=int, default=250)
    p.add_argument("--confirm-seed", type=int, default=1)
    p.add_argument("--dry-run", action="store_true", help="fit and report, write nothing")
    args = p.parse_args(argv)
    if args.frames < 5 or not 0 < args.holdout < 1:
        raise SystemExit("--frames ≥ 5 and 0 < --holdout < 1")
    if args.side_cells < 3 or args.side_cells % 2 == 0:
        raise SystemExit("--side-cells: an odd number ≥ 3")
    engine = Engine(args.bundle, precision="int8", threads=args.threads, runtime=args.runtime,
                    lidar_select=False)
    if not engine.has_confidence:
        raise SystemExit(f"{args.bundle}: the selection needs a bundle with a confidence output")
    gate = args.max_confidence or np.inf
    rows = collect(engine, args.data, args.frames, args.rig_share, args.seed, args.side_cells,
                   gate)
    n_hold = max(1, int(round(len(rows) * args.holdout)))
    fit_rows, hold_rows = rows[n_hold:], rows[:n_hold]
    select = fit(fit_rows, args.hidden, args.steps, args.seed, args.side_cells, gate,
                 args.min_margin)
    heldout = report("held-out (stereo only)", hold_rows, score, select)
    scale, bias = logistic_share(*replaced_cells(fit_rows, select))
    z, n, k = replaced_cells(hold_rows, select)
    if len(z):
        trust = replace(select, confidence_scale=scale, confidence_bias=bias) \
            .chosen_confidence(z)
        predicted = float((n * trust).sum() / n.sum())
        heldout["replaced_within_1px"] = dict(predicted=predicted,
                                              measured=float(k.sum() / n.sum()),
                                              pixels=int(n.sum()))
        print(f"held-out replaced pixels ({int(n.sum())}): within 1 px {k.sum() / n.sum():.3f},"
              f" confidence predicts {predicted:.3f}")
    select = fit(rows, args.hidden, args.steps, args.seed, args.side_cells, gate,  # stored
                 args.min_margin)
    z, n, k = replaced_cells(rows, select)
    if not len(z):
        raise SystemExit("fit_edge_select: the choice replaced no cell on the fitting frames")
    scale, bias = logistic_share(z, n, k)
    select = replace(select, confidence_scale=scale, confidence_bias=bias)
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
