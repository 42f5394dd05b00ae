"""Fit the LiDAR selection (`edge.runtime.lidar_select`) on a bundle's own outputs and store
it in the bundle's model.json.

    python tools/fit_select.py BUNDLE --data data/things_select [--frames 300] [--rig-share 0.4]
        [--holdout 0.25] [--max-disagreement 16] [--max-confidence 0.9]
        [--lidar projected|gt] [--runtime onnxruntime] [--side-cells 0] [--blend 1]
        [--confirm DIR [--confirm-frames 250] [--confirm-seed 1]] [--dry-run]

Each frame is a things sample the network never trained on (or, `--rig-share` of them, a rig
frame from training seeds), at the bundle's size, with a LiDAR pattern drawn as in training
(`GtLidarPattern.random`, never none), by default read in the right view and projected into
the left with the occlusion filter (`--lidar projected`: the wrong points a robot's projected
scan keeps; `--lidar gt`: exact rows, as the Aloe recipe samples them). The bundle runs on
it (int8, its default iterations);
at each 2×2 cell where the network's disparity and the nearest LiDAR point's differ and the
network is not confident, the label is which of the two is nearer the GT over the cell's
pixels, weighted by how much nearer (so the fit minimises the end-point error of the
choice). A held-out share of the frames reports what the fitted choice does to EPE and
bad-3 there, over all of them and per source (rig / things: a mix can hide a loss on the
rarer one); nothing from the evaluation sets is read. Last, the confidence the engine gives
the pixels the choice replaces is fitted on the same frames: sigmoid(a · logit + b) as the
share of those pixels within 1 px of the truth (held-out: predicted vs measured). With
`--confirm`, the stored fit is also scored on frames from another folder and seed.

`--side-cells 3 --blend 0.5` fits the four-candidate variant (docs/experiments.md): the
network's own near and far sides are candidates too, at the cells where they
differ as well; each candidate's label is whether it is nearer the truth than the network,
errors above 16 px counting at half their excess. More accurate on every synthetic set, but
1.65× the shipped stage's cost: not the shipped recipe.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from edge_depth.model.data import TRAIN_SEED_LIMIT, sample_to_arrays
from edge_depth.runtime.cells import CELL_PX, cell_pixels
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.lidar_select import LidarSelect, available, selection_features
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim.gt_lidar import GtLidarPattern
from edge_depth.sim.things_store import list_things, read_things

MAX_WEIGHT_PX = 8.0  # a pixel's share of its cell's weight (how much nearer), capped
MAX_ERROR_PX = 16.0  # a pixel's error, capped, in `candidate_row`'s capped sums


def frames(data: Path, count: int, rig_share: float, size: tuple[int, int], seed: int,
           lidar_source: str = "projected"):
    """Yield (source "rig" | "things", left, right, sparse, gt), each (H, W) at the bundle's
    size."""
    files = list_things(data)
    if not files:
        raise SystemExit(f"{data}: no things samples (NNNNNNN.npz); render them with "
                         "`edge-depth synth --world things --out DIR`")
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(files))
    rig = RigConfig()
    used = 0
    for i in range(count):
        source = "rig" if rng.random() < rig_share else "things"
        if source == "rig":
            arrays = sample_to_arrays(make_sample(int(rng.integers(0, TRAIN_SEED_LIMIT)), rig,
                                                  "beams16"))
            left, right, gt, sparse = (arrays["left"], arrays["right"], arrays["gt"],
                                       arrays["sparse"] * arrays["valid"])
        else:
            things = read_things(files[order[used % len(files)]])
            used += 1
            left, right, gt = things["left"], things["right"], things["disp_left"]
            pattern = GtLidarPattern.random(gt.shape[0], rng, none_share=0.0)
            if lidar_source == "projected":
                sparse = pattern.sample_projected(things["disp_right"], rng)
            else:
                sparse = pattern.sample(gt, rng)
        if (left.shape[1], left.shape[0]) != size:
            raise SystemExit(f"frame {i}: {left.shape[::-1]} is not the bundle's size {size}")
        yield source, left, right, np.asarray(sparse, np.float32), np.asarray(gt, np.float32)


def known_cell_pixels(cells: np.ndarray, disparity: np.ndarray, gt: np.ndarray
                      ) -> tuple[np.ndarray, ...]:
    """What scoring a per-cell choice needs, flat: (gt, known (its finite, positive pixels),
    the network's error per pixel, the given cells' known pixels, which cell each belongs
    to)."""
    gt = np.asarray(gt, np.float32).ravel()
    known = np.isfinite(gt) & (gt > 0)
    err_net = np.abs(disparity.ravel() - gt)
    pixels, owner = cell_pixels(cells, disparity.shape)
    keep = known[pixels]
    return gt, known, err_net, pixels[keep], owner[keep]


def frame_row(source: str, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
              confidence: np.ndarray, sparse: np.ndarray, gt: np.ndarray,
              max_disagreement_px: float = np.inf, max_confidence: float = np.inf,
              side_cells: int = 0) -> dict:
    """One frame's candidate cells (`selection_features`) as `candidate_row` scores them."""
    features, cells, values = selection_features(left, right, disparity, confidence, sparse,
                                                 max_disagreement_px, max_confidence,
                                                 side_cells)
    return candidate_row(source, features, cells, values.reshape(len(cells), -1), disparity,
                         gt)


def candidate_row(source: str, features: np.ndarray, cells: np.ndarray, values: np.ndarray,
                  disparity: np.ndarray, gt: np.ndarray) -> dict:
    """What fitting and scoring a per-cell choice need: the features, and per cell (rows)
    and candidate (columns: the network's, then each of values' (N, C)) the summed error,
    the same capped per pixel at MAX_ERROR_PX, the bad-3 count and the pixels within 1 px
    over the cell's known pixels; and the frame's own totals (known pixels, the network's
    summed error and bad-3 count)."""
    gt, known, err_net, pixels, owner = known_cell_pixels(cells, disparity, gt)
    errors = [err_net[pixels]] + [np.abs(values[owner, i] - gt[pixels])
                                  for i in range(values.shape[1])]

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
            max_disagreement_px: float = np.inf, lidar_source: str = "projected",
            max_confidence: float = np.inf, side_cells: int = 0) -> list[dict]:
    """`frame_row` for each of `frames`, through the bundle (progress on stderr)."""
    out = []
    start = time.perf_counter()
    for i, (source, left, right, sparse, gt) in enumerate(frames(data, count, rig_share,
                                                                 engine.size, seed, lidar_source)):
        result = engine.infer(left, right, sparse)
        out.append(frame_row(source, left, right, result.disparity, result.confidence, sparse,
                             gt, max_disagreement_px, max_confidence, side_cells))
        if (i + 1) % 20 == 0 or i + 1 == count:
            print(f"fit_select: {i + 1}/{count} frames ({time.perf_counter() - start:.0f} s)",
                  file=sys.stderr, flush=True)
    return out


def fit_perceptron(x: np.ndarray, y: np.ndarray, w: np.ndarray, hidden: int, steps: int,
                   seed: int, per_weight: bool = False) -> tuple[np.ndarray, ...]:
    """Weighted logistic losses on one hidden ReLU layer, k outputs (y, w: (N, k)), Adam at
    1e-2 with a cosine schedule over `steps` batches of up to 65 536 rows (torch: the
    training extra). per_weight: each batch's loss is divided by its summed weight instead
    of its size. Returns (mean, std, w1 (F, K), b1 (K,), w2 (K, k), b2 (k,)), float32: the
    standardisation and the two layers."""
    import torch

    mean, std = x.mean(0), x.std(0) + 1e-6
    torch.manual_seed(seed)
    xt = torch.from_numpy((x - mean) / std)
    yt, wt = torch.from_numpy(y.astype(np.float32)), torch.from_numpy(w.astype(np.float32))
    model = torch.nn.Sequential(torch.nn.Linear(x.shape[1], hidden), torch.nn.ReLU(),
                                torch.nn.Linear(hidden, y.shape[1]))
    opt = torch.optim.Adam(model.parameters(), 1e-2)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    gen = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        idx = torch.randint(0, len(yt), (min(65536, len(yt)),), generator=gen)
        if per_weight:
            loss = torch.nn.functional.binary_cross_entropy_with_logits(
                model(xt[idx]), yt[idx], wt[idx], reduction="sum") / (wt[idx].sum() + 1e-6)
        else:
            loss = torch.nn.functional.binary_cross_entropy_with_logits(model(xt[idx]),
                                                                        yt[idx], wt[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    first, second = model[0], model[2]
    return (mean.astype(np.float32), std.astype(np.float32),
            first.weight.detach().numpy().T.copy(), first.bias.detach().numpy().copy(),
            second.weight.detach().numpy().T.copy(), second.bias.detach().numpy().copy())


def candidate_gains(rows: list[dict], blend: float) -> tuple[np.ndarray, np.ndarray]:
    """(features (N, F), gain (N, C)): per cell how much lower each candidate's summed error
    is than the network's, with each pixel's error above MAX_ERROR_PX counted at `blend` of
    its excess (1: the raw error; 0: capped)."""
    x = np.concatenate([r["features"] for r in rows])
    cost = np.concatenate([r["capped"] + blend * (r["err"] - r["capped"]) for r in rows])
    return x, cost[:, :1] - cost[:, 1:]


def fit(rows: list[dict], hidden: int, steps: int, seed: int,
        max_disagreement_px: float = np.inf, max_confidence: float = np.inf,
        side_cells: int = 0, blend: float = 1.0) -> LidarSelect:
    """Weighted logistic losses, one hidden ReLU layer, Adam (`fit_perceptron`): per
    candidate, whether it is nearer the truth than the network over the cell, weighted by how
    much (`candidate_gains`, capped at MAX_WEIGHT_PX a pixel); a candidate that is not
    `available` at a cell carries no loss there."""
    x, gain = candidate_gains(rows, blend)
    weight = np.minimum(np.abs(gain), MAX_WEIGHT_PX * CELL_PX * CELL_PX)
    if side_cells:
        weight = weight * available(x, max_disagreement_px)
    mean, std, w1, b1, w2, b2 = fit_perceptron(x, gain > 0, weight, hidden, steps, seed)
    if not side_cells:
        w2, b2 = w2[:, 0].copy(), float(b2[0])
    return LidarSelect(mean=mean, std=std, w1=w1, b1=b1, w2=w2, b2=b2,
                       max_disagreement_px=max_disagreement_px,
                       max_confidence=max_confidence, side_cells=side_cells)


def replaced_cells(rows: list[dict], select) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Over the cells the choice replaces (`select.choose`: LidarSelect's):
    (margins: the chosen logit over the network's, known pixels, of those within 1 px)."""
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


def logistic_share(z: np.ndarray, n: np.ndarray, k: np.ndarray) -> tuple[float, float]:
    """(scale, bias) maximising the likelihood of k of n pixels being right at each score z
    under p = sigmoid(scale · z + bias): a two-parameter weighted logistic fit (Newton)."""
    x = np.stack([z.astype(np.float64), np.ones(len(z))], 1)
    theta = np.zeros(2)
    for _ in range(50):
        p = 1.0 / (1.0 + np.exp(-x @ theta))
        grad = x.T @ (k - n * p)
        hess = (x * (n * p * (1 - p))[:, None]).T @ x + 1e-9 * np.eye(2)
        step = np.linalg.solve(hess, grad)
        theta += step
        if np.abs(step).max() < 1e-8:
            break
    return float(theta[0]), float(theta[1])


def score(rows: list[dict], select) -> tuple[float, float]:
    """Mean EPE and bad-3 % over the frames' known pixels, with or without the choice
    (`select.choose`: LidarSelect's; None: the network's values)."""
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


def report(label: str, rows: list[dict], score_fn, select) -> dict:
    """Print and return EPE and bad-3 before → after the choice, over all frames and per
    source (the mix can hide a loss on the rarer one). score_fn(rows, select or None) →
    (EPE, bad-3 %)."""
    out = {}
    for source in ("all", "rig", "things"):
        part = [r for r in rows if source in ("all", r["source"])]
        if part:
            before, after = score_fn(part, None), score_fn(part, select)
            out[source] = dict(frames=len(part), epe=[before[0], after[0]],
                               bad3=[before[1], after[1]])
            print(f"{label} {source} ({len(part)} frames): EPE {before[0]:.4f} → "
                  f"{after[0]:.4f} px, bad-3 {before[1]:.3f} → {after[1]:.3f} %")
    return out


def store(bundle: Path, key: str, entry: dict) -> None:
    """Write `entry` under `key` in the bundle's model.json (the rest kept)."""
    meta_path = bundle / "model.json"
    meta = json.loads(meta_path.read_text())
    meta[key] = entry
    meta_path.write_text(json.dumps(meta, indent=2))  # as export.py and quantize.py write it
    print(f"wrote {key} into {meta_path}")


def add_fit_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of this tool: the bundle, the frames, the fit and the confidence gate."""
    p.add_argument("bundle", type=Path)
    p.add_argument("--data", type=Path, required=True,
                   help="things samples the network never trained on")
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--rig-share", type=float, default=0.4)
    p.add_argument("--holdout", type=float, default=0.25)
    p.add_argument("--hidden", type=int, default=32)
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--runtime", default="onnxruntime")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--max-confidence", type=float, default=0.9,
                   help="act only on cells whose mean confidence is below this (0 = any cell)")
    p.add_argument("--confirm", type=Path, help="also score on frames from this folder")
    p.add_argument("--confirm-frames", type=int, default=250)
    p.add_argument("--confirm-seed", type=int, default=1)
    p.add_argument("--dry-run", action="store_true", help="fit and report, write nothing")


def fitting_engine(args: argparse.Namespace) -> Engine:
    """Both fit tools' checks of their shared arguments, and the bundle's int8 engine without
    either selection it may already hold: the fits are on the network's own outputs (an
    engine with its edge selection on fitted a refit of that stage on its own choices)."""
    if args.frames < 5 or not 0 < args.holdout < 1:
        raise SystemExit("--frames ≥ 5 and 0 < --holdout < 1")
    engine = Engine(args.bundle, precision="int8", threads=args.threads, runtime=args.runtime,
                    lidar_select=False, refine="off", edge_median="off")
    if not engine.has_confidence:
        raise SystemExit(f"{args.bundle}: the selection needs a bundle with a confidence output")
    return engine


def calibrate(select, fit_rows: list[dict], hold_rows: list[dict], heldout: dict):
    """`select` with the confidence of the pixels it replaces fitted on fit_rows
    (`logistic_share` of the margins); on hold_rows, predicted vs measured share within 1 px
    printed and added to `heldout` (when it replaces any)."""
    z, n, k = replaced_cells(fit_rows, select)
    if not len(z):
        raise SystemExit("the choice replaced no cell on the fitting frames; nothing to "
                         "calibrate its confidence on")
    scale, bias = logistic_share(z, n, k)
    select = replace(select, confidence_scale=scale, confidence_bias=bias)
    z, n, k = replaced_cells(hold_rows, select)
    if len(z):
        predicted = float((n * select.chosen_confidence(z)).sum() / n.sum())
        heldout["replaced_within_1px"] = dict(predicted=predicted,
                                              measured=float(k.sum() / n.sum()),
                                              pixels=int(n.sum()))
        print(f"held-out replaced pixels ({int(n.sum())}): within 1 px {k.sum() / n.sum():.3f},"
              f" confidence predicts {predicted:.3f}")
    return select


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_fit_arguments(p)
    # defaults: the variant the held-out frames chose (docs/experiments.md),
    # the one the shipped bundle holds
    p.add_argument("--max-disagreement", type=float, default=16.0,
                   help="px: the LiDAR point is a candidate where it differs from the "
                        "network's value by at most this (0 = any)")
    p.add_argument("--side-cells", type=int, default=0,
                   help="the network's near / far sides (max / min over this many cells "
                        "square, odd; 3 when tried) are candidates too: more "
                        "accurate, 1.65× the cost (not shipped); 0: the LiDAR point only")
    p.add_argument("--blend", type=float, default=1.0,
                   help="a pixel's error above 16 px counts at this share of its excess in "
                        "the fit (1: raw errors, the shipped recipe; 0.5 with sides)")
    p.add_argument("--lidar", choices=("projected", "gt"), default="projected",
                   help="things frames' LiDAR: projected from the right view (default) or "
                        "exact GT rows")
    args = p.parse_args(argv)
    if args.side_cells and (args.side_cells < 3 or args.side_cells % 2 == 0):
        raise SystemExit("--side-cells: 0, or an odd number ≥ 3")
    engine = fitting_engine(args)
    cap = args.max_disagreement or np.inf
    gate = args.max_confidence or np.inf

    def rows_of(data: Path, count: int, seed: int) -> list[dict]:
        return collect(engine, data, count, args.rig_share, seed, cap, args.lidar, gate,
                       args.side_cells)

    def fitted(rows: list[dict]) -> LidarSelect:
        return fit(rows, args.hidden, args.steps, args.seed, cap, gate, args.side_cells,
                   args.blend)

    rows = rows_of(args.data, args.frames, args.seed)
    n_hold = max(1, int(round(len(rows) * args.holdout)))
    fit_rows, hold_rows = rows[n_hold:], rows[:n_hold]
    select = fitted(fit_rows)
    heldout = report("held-out", hold_rows, score, select)
    calibrate(select, fit_rows, hold_rows, heldout)
    select = calibrate(fitted(rows), rows, [], {})  # stored: fitted on every frame
    confirmed = None
    if args.confirm is not None:
        confirmed = report("confirmation", rows_of(args.confirm, args.confirm_frames,
                                                   args.confirm_seed), score, select)
    if args.dry_run:
        return 0
    store(args.bundle, "lidar_select", dict(select.to_meta(), frames=args.frames,
                                            data=str(args.data), rig_share=args.rig_share,
                                            lidar=args.lidar, seed=args.seed, blend=args.blend,
                                            heldout=heldout, confirmation=confirmed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
