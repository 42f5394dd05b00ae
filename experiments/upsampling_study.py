"""How much of the 1/8-resolution ceiling the upsampling recovers.

    python experiments/upsampling_study.py DATA_DIR [--model CKPT] [--iters 4] [--json OUT]

For each scene folder: the ground truth taken to 1/8 (mean of each 8x8 cell's known values)
and brought back bilinearly or by nearest neighbour (the ceiling of any 1/8 output upsampled
without the image); then the network's own 1/8 estimate after `--iters` steps, upsampled
bilinearly, by its convex upsampling, and by convex upsampling + the refinement stage (when
the checkpoint has one). For refinement version 4 also its 1/4 estimate alone, and an oracle
that takes whichever of the convex and the 1/4 estimate is closer to the GT at each pixel (the
ceiling of its gate; it reads the GT, so it is a diagnosis, not a method). EPE / bad-1 / bad-3
over GT-valid pixels, means over scenes.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from edge_depth.metrics import disparity_metrics
from edge_depth.sim.folder import list_scene_folders, read_scene_folder

FACTOR = 8


def gt_at_eighth(gt: np.ndarray) -> np.ndarray:
    """(H/8, W/8) mean of the known GT in each cell, in 1/8-resolution pixels (0 = none)."""
    known = np.isfinite(gt) & (gt > 0)
    h, w = (gt.shape[0] // FACTOR) * FACTOR, (gt.shape[1] // FACTOR) * FACTOR
    val = np.where(known, gt, 0.0)[:h, :w].reshape(h // FACTOR, FACTOR, w // FACTOR, FACTOR)
    cnt = known[:h, :w].reshape(h // FACTOR, FACTOR, w // FACTOR, FACTOR).sum((1, 3))
    return np.where(cnt > 0, val.sum((1, 3)) / np.maximum(cnt, 1), 0.0) / FACTOR


def up(low: np.ndarray, size: tuple[int, int], interpolation: int) -> np.ndarray:
    return cv2.resize(low.astype(np.float32), size, interpolation=interpolation) * FACTOR


def network_variants(net, scene, iters: int) -> dict[str, np.ndarray]:
    import torch

    from edge_depth.model.network import convex_upsample

    t = lambda a: torch.from_numpy(a.astype(np.float32))[None, None]  # noqa: E731
    sparse = np.where(np.isfinite(scene.sparse) & (scene.sparse > 0), scene.sparse, 0)
    left, right = t(scene.left), t(scene.right)
    sparse, valid = t(sparse), t((sparse > 0).astype(np.float32))
    with torch.no_grad():
        state = net.encode(left, right, sparse, valid)
        d, h, hl = state["disparity"], state["hidden"], state["hidden_low"]
        for _ in range(iters):
            d, h, hl, mask = net.step(state, d, h, hl)
        size = (scene.left.shape[1], scene.left.shape[0])
        out = {"net 1/8, bilinear": up(d[0, 0].numpy(), size, cv2.INTER_LINEAR),
               "net 1/8, convex": convex_upsample(d, mask, FACTOR)[0, 0].numpy()}
        # the confidence head (the kept version) does not move the disparity: no row of its own
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data", type=Path)
    p.add_argument("--model", type=Path, default=Path("edge/models/sparse_stereo.pt"))
    p.add_argument("--iters", type=int, default=4)
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    folders = list_scene_folders(args.data)
    if not folders:
        p.error(f"no scene folders under {args.data}")
    from edge_depth.tools.export import load_checkpoint

    net, _ = load_checkpoint(args.model)  # once, not per scene
    rows: dict[str, list[dict]] = {}
    for folder in folders:
        scene = read_scene_folder(folder)
        size = (scene.left.shape[1], scene.left.shape[0])
        low = gt_at_eighth(scene.disp)
        preds = {"GT 1/8, bilinear": up(low, size, cv2.INTER_LINEAR),
                 "GT 1/8, nearest": up(low, size, cv2.INTER_NEAREST)}
        preds.update(network_variants(net, scene, args.iters))
        for name, pred in preds.items():
            rows.setdefault(name, []).append(disparity_metrics(pred, scene.disp))
    summary = {k: {m: float(np.mean([r[m] for r in v])) for m in ("epe", "bad1", "bad3")}
               for k, v in rows.items()}
    print("| upsampling | EPE px | bad-1 % | bad-3 % |\n|---|---|---|---|")
    for name, m in summary.items():
        print(f"| {name} | {m['epe']:.2f} | {m['bad1']:.1f} | {m['bad3']:.1f} |")
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
