"""Evaluate disparity methods on scene folders against their ground truth, in one run.

    python tools/evaluate.py DATA_DIR [--model CHECKPOINT_OR_BUNDLE] [--precision int8]
        [--methods net,sgbm,lidar-nearest,lidar-linear] [--no-lidar] [--iters N] [--json OUT]
        [--plot OUT.png] [--picture OUT.jpg]

Methods: net; net-nolidar (the net with its LiDAR input zeroed: stereo only; --no-lidar adds
it); sgbm (holes left as holes); sgbm-filled (holes take the row's nearest valid value);
sgbm+lidar (the trivial fusion: SGBM where it matched, LiDAR-nearest in its holes);
guided-sgm (census SGM, `edge.guided_sgm`, holes after its left-right check take the row's
nearest valid value); guided-sgm+lidar (the same SGM with Poggi et al.'s LiDAR guidance of its
cost, the LiDAR value written at its pixels and the nearest LiDAR point in its holes);
lidar-nearest; lidar-linear. SGBM's and guided SGM's disparity count follows each scene's GT
range (rounded up to 16, at least 64).

The network is a training checkpoint (.pt, run with PyTorch, any input size: padded to the
downsample factor) or an exported bundle directory (run by the robot-side engine with its
flags: --runtime, --precision, --scale budget|fit|native, --refine band|off, --edge-median;
the settings left unsaid are the engine's defaults and those its model.json declares: the
shipped one's weighted median 9x9/2); the default is the shipped bundle.

Metrics over all GT-valid pixels, holes counting as errors: EPE, bad-1/2/3, density, and with
focal/baseline from meta.json the KITTI depth metrics (RMSE, MAE in mm; iRMSE, iMAE in 1/km);
for a model with a confidence output, its calibration: kept@t, the share of pixels with
confidence ≥ t (%), and bad1@t, the bad-1 among them, for t = 0.5, 0.7, 0.9;
`ms` is the median time per pair. `--iters 1,2,4,8` evaluates the network at each count
(keys net@1, net@2, ...) and plots the EPE-vs-iterations curve with --plot. `--picture`
draws the first scene: its left image and GT, then each method's |error| (black = exact,
white ≥ 4 px, red = hole) with its bad-3 — where a method loses, not only how much.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from edge_depth.baselines import (
    fill_row_nearest,
    lidar_linear,
    lidar_nearest,
    make_sgbm,
    sgbm_disparities_for,
    sgbm_disparity,
    sgbm_lidar_fusion,
)
from edge_depth.guided_sgm import GuidedSgmConfig, guided_sgm_filled, guided_sgm_lidar
from edge_depth.metrics import confidence_calibration, depth_metrics, disparity_metrics
from edge_depth.runtime.engine import DEFAULT_BUNDLE
from edge_depth.runtime.graphs import load_bundle_meta
from edge_depth.runtime.options import EngineOptions, add_engine_arguments, options_from_args
from edge_depth.sim.folder import list_scene_folders, read_scene_folder

# the engine settings a bundle is evaluated with (the others: EngineOptions' defaults)
ENGINE_FLAGS = ("precision", "runtime", "bf16", "int8_encoder", "scale", "edge_median",
                "align_lidar", "denoise_lidar", "refine")

METHODS = ("net", "sgbm", "lidar-nearest", "lidar-linear")
ALL_METHODS = METHODS + ("net-nolidar", "sgbm-filled", "sgbm+lidar", "guided-sgm",
                         "guided-sgm+lidar")


class TorchNet:
    """A training checkpoint run with PyTorch (the training extra)."""

    def __init__(self, path: Path) -> None:
        import torch

        from edge_depth.tools.export import load_checkpoint

        self.net, _ = load_checkpoint(path)
        self.torch = torch

    def __call__(self, left, right, sparse, iters: int):
        """(disparity (H, W), confidence (H, W) or None)."""
        torch = self.torch
        f = self.net.config.downsample
        h, w = left.shape
        ph, pw = -h % f, -w % f  # pad to a multiple of the downsample factor
        def t(a):  # noqa: E306
            a = np.pad(a.astype(np.float32), ((0, ph), (0, pw)), mode="edge")
            return torch.from_numpy(a)[None, None]
        valid = (sparse > 0).astype(np.float32)
        with torch.no_grad():
            outs, logit = self.net(t(left), t(right), t(sparse * valid), t(valid), iters,
                                   with_confidence=True)
        confidence = None if logit is None else torch.sigmoid(logit)[0, 0, :h, :w].numpy()
        return outs[-1][0, 0, :h, :w].numpy(), confidence


class BundleNet:
    """An exported bundle run by the robot-side engine (ONNX Runtime or OpenVINO)."""

    def __init__(self, path: Path, options: EngineOptions | None = None) -> None:
        from edge_depth.runtime.engine import Engine

        self.engine = Engine(path, options)

    def __call__(self, left, right, sparse, iters: int):
        result = self.engine.infer(left, right, sparse, iters=iters)
        return result.disparity, result.confidence


def bundle_iters(model: Path) -> int:
    """The iterations a bundle runs at by default (its model.json's default_iters); 4 for a
    training checkpoint or a folder without one."""
    if not (model / "model.json").is_file():
        return 4
    return int(load_bundle_meta(model).get("default_iters", 4))


def load_net(model: Path, options: EngineOptions | None = None):
    """A bundle directory run by the engine with `options`, or a training checkpoint."""
    return BundleNet(model, options) if model.is_dir() else TorchNet(model)


def evaluate(folders: list[Path], methods: list[str], iters_list: list[int],
             model: Path | None, options: EngineOptions | None = None,
             first: dict | None = None) -> dict[str, dict[str, float]]:
    """Mean metrics per method; a bundle runs with the engine `options` (default: its
    defaults). `first`, if given, receives the first scene ("scene") and each method's
    prediction on it (by method name), for `picture`."""
    net = None
    if {"net", "net-nolidar"} & set(methods):
        net = load_net(model, options)
        if isinstance(net, BundleNet):
            print(f"{model}: {net.engine.describe()}", file=sys.stderr)
    refined = isinstance(net, BundleNet) and net.engine.band is not None
    per_method: dict[str, list[dict]] = {}
    for folder in folders:
        scene = read_scene_folder(folder)
        if scene.disp is None or scene.sparse is None:
            raise SystemExit(f"{folder}: needs disp.pfm and sparse.pfm")
        gt_max = float(np.max(scene.disp[np.isfinite(scene.disp)], initial=0.0))
        sgbm = make_sgbm(sgbm_disparities_for(gt_max))
        runs = []  # (name, method, iterations)
        for method in methods:
            if method in ("net", "net-nolidar"):
                for iters in iters_list:
                    runs.append((f"{method}@{iters}" if len(iters_list) > 1 else method,
                                 method, iters))
            else:
                runs.append((method, method, 0))
        for name, method, iters in runs:
            start = time.perf_counter()
            pred, confidence = predict(method, scene, net, sgbm, iters)
            ms = (time.perf_counter() - start) * 1000
            m = disparity_metrics(pred, scene.disp)
            if "focal_px" in scene.meta and "baseline_m" in scene.meta:
                m.update(depth_metrics(pred, scene.disp, scene.meta["focal_px"],
                                       scene.meta["baseline_m"]))
            if confidence is not None:
                m.update(confidence_calibration(pred, scene.disp, confidence))
            m["ms"] = ms
            per_method.setdefault(name, []).append(m)
            if first is not None and folder == folders[0]:
                first["scene"] = scene
                staged = refined and method in ("net", "net-nolidar")
                label = f"{name} + band" if staged else name
                first.setdefault("predictions", {})[label] = (pred, m["bad3"])
    summary = {}
    for name, rows in per_method.items():
        summary[name] = {k: _mean([r[k] for r in rows]) for k in rows[0] if k != "ms"}
        summary[name]["ms"] = float(np.median([r["ms"] for r in rows]))
        summary[name]["samples"] = len(rows)
    return summary


def predict(method: str, scene, net, sgbm, iters: int):
    """One method's (disparity, confidence or None) on a scene folder's pair and LiDAR."""
    valid = scene.sparse > 0
    if method == "net":
        return net(scene.left, scene.right, scene.sparse, iters)
    if method == "net-nolidar":
        return net(scene.left, scene.right, np.zeros_like(scene.sparse), iters)
    if method == "sgbm":
        return sgbm_disparity(scene.left, scene.right, sgbm), None
    if method == "sgbm-filled":
        return fill_row_nearest(sgbm_disparity(scene.left, scene.right, sgbm)), None
    if method == "sgbm+lidar":
        return sgbm_lidar_fusion(sgbm_disparity(scene.left, scene.right, sgbm),
                                 scene.sparse, valid), None
    if method in ("guided-sgm", "guided-sgm+lidar"):
        config = GuidedSgmConfig(num_disparities=sgbm.getNumDisparities())  # SGBM's range
        if method == "guided-sgm":
            return guided_sgm_filled(scene.left, scene.right, config), None
        return guided_sgm_lidar(scene.left, scene.right, scene.sparse, config), None
    if method == "lidar-nearest":
        return lidar_nearest(scene.sparse, valid), None
    return lidar_linear(scene.sparse, valid), None


def _mean(values: list[float]) -> float:
    """Mean over the scenes that have the value (NaN: e.g. nothing kept at a threshold)."""
    finite = [v for v in values if np.isfinite(v)]
    return float(np.mean(finite)) if finite else float("nan")


def markdown_table(summary: dict[str, dict[str, float]]) -> str:
    cols = ["epe", "bad1", "bad2", "bad3", "density", "rmse_mm", "mae_mm", "irmse", "imae",
            "ms", "kept@0.5", "bad1@0.5", "kept@0.7", "bad1@0.7", "kept@0.9", "bad1@0.9"]
    cols = [c for c in cols if any(c in v for v in summary.values())]
    lines = ["| method | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for name, m in summary.items():
        lines.append(f"| {name} | " + " | ".join(f"{m[c]:.2f}" if c in m else "–" for c in cols)
                     + " |")
    return "\n".join(lines)


def picture(first: dict, columns: int = 3, scale: float = 0.5) -> np.ndarray:
    """The first scene's tiles (BGR uint8, each `scale` × the scene): left image, GT, then
    each method's |error| (grey where the GT is unknown)."""
    import cv2

    from edge_depth.demo import colorize_disparity, error_map, labelled

    scene = first["scene"]
    known = np.isfinite(scene.disp) & (scene.disp > 0)
    gt = np.where(known, scene.disp, 0).astype(np.float32)
    heats = []
    for pred, _ in first["predictions"].values():
        heat = error_map(pred, gt)
        heat[~known] = 64
        heats.append(heat)
    images = [cv2.cvtColor(np.asarray(scene.left, np.uint8), cv2.COLOR_GRAY2BGR),
              colorize_disparity(gt, float(gt.max()))] + heats
    names = ["left", "ground truth"] + [f"{name}: bad-3 {bad3:.2f} %" for name, (_, bad3)
                                        in first["predictions"].items()]
    tiles = [labelled(cv2.resize(im, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA),
                      name) for im, name in zip(images, names, strict=True)]
    tiles += [np.zeros_like(tiles[0])] * (-len(tiles) % columns)
    return np.vstack([np.hstack(tiles[i:i + columns]) for i in range(0, len(tiles), columns)])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data", type=Path, help="a scene folder or a folder of them")
    p.add_argument("--model", type=Path, default=DEFAULT_BUNDLE,
                   help="training checkpoint (.pt) or bundle directory (default: the shipped "
                        "bundle)")
    p.add_argument("--methods", default=",".join(METHODS))
    p.add_argument("--no-lidar", action="store_true",
                   help="also run the net stereo-only (LiDAR input zeroed): net-nolidar")
    p.add_argument("--iters", default=None, help="GRU iterations, e.g. 4 or 1,2,4,8,16 "
                   "(default: a bundle's own, model.json's default_iters; a checkpoint's 4)")
    p.add_argument("--no-select", action="store_true",
                   help="a bundle without its LiDAR selection, if it has one")
    add_engine_arguments(p, only=ENGINE_FLAGS)  # a bundle's
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--plot", type=Path, default=None, help="EPE-vs-iterations PNG")
    p.add_argument("--picture", type=Path, default=None,
                   help="the first scene's left image, GT and each method's |error| (JPEG/PNG)")
    args = p.parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if args.no_lidar and "net-nolidar" not in methods:
        methods.append("net-nolidar")
    unknown = sorted(set(methods) - set(ALL_METHODS))
    if unknown:
        p.error(f"unknown methods {unknown}; choose from {', '.join(ALL_METHODS)}")
    if args.iters is None:
        args.iters = str(bundle_iters(args.model))
    try:
        iters_list = [int(v) for v in args.iters.split(",")]
    except ValueError:
        p.error(f"--iters: expected integers like 4 or 1,2,4, got {args.iters!r}")
    if {"net", "net-nolidar"} & set(methods) and not args.model.exists():
        p.error(f"--model {args.model}: no such checkpoint or bundle")
    if args.picture and args.picture.suffix.lower() not in (".jpg", ".jpeg", ".png"):
        p.error(f"--picture {args.picture}: name a .jpg or .png file")
    if (args.refine is not None or args.edge_median is not None) and not args.model.is_dir():
        p.error("--refine and --edge-median are stages of the engine: give a bundle "
                "(--model DIR)")
    folders = list_scene_folders(args.data)
    if not folders:
        p.error(f"no scene folders under {args.data}")
    options = options_from_args(args, only=ENGINE_FLAGS, lidar_select=not args.no_select)
    first: dict | None = {} if args.picture else None
    summary = evaluate(folders, methods, iters_list, args.model, options, first)
    print(markdown_table(summary))
    if args.picture:
        write_picture(args.picture, first, folders[0])
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2))
    if args.plot and "net" in methods:
        plot_iterations(args.plot, summary, iters_list, str(args.data))
    return 0


def write_picture(path: Path, first: dict | None, folder: Path) -> None:
    """--picture: the first scene's left image, GT and each method's |error|, as JPEG or PNG."""
    import cv2

    jpeg = path.suffix.lower() in (".jpg", ".jpeg")
    if not cv2.imwrite(str(path), picture(first), [cv2.IMWRITE_JPEG_QUALITY, 85] if jpeg else []):
        raise SystemExit(f"--picture {path}: could not write it (does its folder exist?)")
    print(f"wrote {path} (the first scene, {folder})")


def plot_iterations(path: Path, summary: dict, iters_list: list[int], title: str) -> None:
    """--plot: the network's EPE against its iterations, the baselines as lines across."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [f"net@{i}" if len(iters_list) > 1 else "net" for i in iters_list]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.plot(iters_list, [summary[k]["epe"] for k in keys], marker="o", label="net")
    for base in ("sgbm", "sgbm-filled", "sgbm+lidar", "guided-sgm", "guided-sgm+lidar",
                 "lidar-nearest", "lidar-linear"):
        if base in summary:
            ax.axhline(summary[base]["epe"], ls="--", label=base, color=None)
    ax.set(xlabel="GRU iterations", ylabel="EPE (px)", xscale="log", title=title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)


if __name__ == "__main__":
    raise SystemExit(main())
