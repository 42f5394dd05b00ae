"""`edge-depth demo`: the embedded default, end to end, with no hardware and no download.

The synthetic rig plays a robot (test-split scenes, 16-beam LiDAR, 10 Hz); the daemon's
pipeline syncs, projects and runs the shipped int8 bundle on every frame and logs everything to
out/demo.mcap. OpenCV SGBM runs on the same pairs in the same run for comparison. The picture
(out/demo.png) shows the first frame: left image, LiDAR, prediction, ground truth and errors.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from edge_depth.baselines import make_sgbm, sgbm_disparity
from edge_depth.metrics import disparity_metrics

DEMO_SEED = 1_000_000  # the first test-split scene: nothing was trained on these


def colorize_disparity(disparity: np.ndarray, max_disparity: float) -> np.ndarray:
    """(H, W) disparity -> (H, W, 3) uint8 BGR (turbo), black where <= 0 or not finite."""
    ok = np.isfinite(disparity) & (disparity > 0)
    scaled = np.clip(np.where(ok, disparity, 0) / max(max_disparity, 1e-6) * 255, 0, 255)
    colour = cv2.applyColorMap(scaled.astype(np.uint8), cv2.COLORMAP_TURBO)
    colour[~ok] = 0
    return colour


def error_map(pred: np.ndarray, gt: np.ndarray, max_error_px: float = 4.0) -> np.ndarray:
    """|pred - gt| as a (H, W, 3) heat map (black = exact, white = >= max_error_px; holes red)."""
    has = np.isfinite(pred) & (pred > 0)
    err = np.clip(np.abs(np.where(has, pred, 0) - gt) / max_error_px * 255, 0, 255)
    heat = cv2.applyColorMap(err.astype(np.uint8), cv2.COLORMAP_INFERNO)
    heat[~has] = (0, 0, 255)
    return heat


def labelled(image: np.ndarray, text: str) -> np.ndarray:
    """A copy of the (H, W, 3) tile with `text` on a black band along its top."""
    out = image.copy()
    cv2.rectangle(out, (0, 0), (out.shape[1], 22), (0, 0, 0), -1)
    cv2.putText(out, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1,
                cv2.LINE_AA)
    return out


def colorize_depth(depth: np.ndarray, max_m: float = 10.0) -> np.ndarray:
    """(H, W) metres -> BGR, near = warm; black where 0."""
    ok = depth > 0
    inverse = np.where(ok, 1.0 / np.maximum(depth, 1e-6), 0)  # as disparity, so near is warm
    colour = colorize_disparity(inverse, 1.0 / 0.5)
    colour[~ok | (depth > max_m)] = 0
    return colour


def colorize_confidence(confidence: np.ndarray) -> np.ndarray:
    """(H, W) confidence 0-1 -> (H, W, 3) uint8 BGR, dark = unsure, bright = sure."""
    return cv2.applyColorMap(np.clip(confidence * 255, 0, 255).astype(np.uint8),
                             cv2.COLORMAP_VIRIDIS)


def demo_picture(left, sparse, pred, gt, sgbm, depth, confidence=None) -> np.ndarray:
    max_d = float(gt.max())
    grey = cv2.cvtColor(left, cv2.COLOR_GRAY2BGR)
    lidar_view = grey.copy()
    ys, xs = np.nonzero(sparse > 0)
    colours = colorize_disparity(sparse[ys, xs][None], max_d)[0]
    for x, y, c in zip(xs, ys, colours, strict=True):
        cv2.circle(lidar_view, (int(x), int(y)), 1, tuple(int(v) for v in c), -1)
    top = np.hstack([labelled(grey, "left (rectified)"),
                     labelled(lidar_view, "LiDAR projected (disparity)"),
                     labelled(colorize_disparity(pred, max_d), "network (int8)"),
                     labelled(colorize_disparity(gt, max_d), "ground truth")])
    bottom = np.hstack([labelled(error_map(pred, gt), "network |error| (0-4 px)"),
                        labelled(colorize_disparity(sgbm, max_d), "OpenCV SGBM"),
                        labelled(error_map(sgbm, gt), "SGBM |error| (red = hole)"),
                        labelled(colorize_depth(depth), "network depth (0.5-10 m)")])
    rows = [top, bottom]
    if confidence is not None:
        blank = np.zeros_like(grey)
        confident = colorize_disparity(np.where(confidence >= 0.9, pred, 0), max_d)
        rows.append(np.hstack([labelled(colorize_confidence(confidence),
                                        "network confidence (error < 1 px)"),
                               labelled(confident, "network where confidence >= 0.9"),
                               blank, blank]))
    return np.vstack(rows)


def _header(engine, iters: int | None, deadline_ms: float | None) -> str:
    """The demo's first line: what runs, and on which CPU (its milliseconds compare with
    like only)."""
    from edge_depth.runtime.backends import cpu_description
    from edge_depth.runtime.engine import usable_cores

    cpu = cpu_description()
    return (f"edge-depth demo: synthetic rig {engine.width}x{engine.height}, 16-beam LiDAR, "
            f"{engine.describe()}, {iters or engine.default_iters} iterations"
            + (f", deadline {deadline_ms:g} ms" if deadline_ms else "")
            + f"; CPU {cpu['model']} ({', '.join(cpu['isa'])}, {usable_cores()} cores)")


def demo_command(out: Path, frames: int, seed: int = DEMO_SEED, precision: str = "auto",
                 iters: int | None = None, deadline_ms: float | None = None,
                 profile: str = "foxglove") -> int:
    from edge_depth.capture.sim import SimSource
    from edge_depth.daemon import Pipeline
    from edge_depth.frame_summary import format_latency, summarise
    from edge_depth.loggers import open_logger
    from edge_depth.runner import run
    from edge_depth.runtime.engine import Engine

    out.mkdir(parents=True, exist_ok=True)
    source = SimSource(frames, seed)
    stereo, lidar = source.calibration
    engine = Engine(precision=precision, threads=2)
    print(_header(engine, iters, deadline_ms))
    matcher = make_sgbm()
    sgbm_rows: list[dict] = []
    picture: list[np.ndarray] = []
    with open_logger(out / "demo.mcap", profile) as logger:
        pipeline = Pipeline(engine, stereo, lidar, logger, iters, deadline_ms)

        def on_output(frame, output) -> None:
            t = time.perf_counter()
            sgbm = sgbm_disparity(output.left, frame.right, matcher)
            ms = (time.perf_counter() - t) * 1000
            gt = output.gt
            m_sgbm = disparity_metrics(sgbm, gt)
            sgbm_rows.append(dict(m_sgbm, ms=ms))
            m = output.metrics
            print(f"frame {frame.seq}: {int((output.sparse > 0).sum())} LiDAR px, "
                  f"{output.result.iterations} it, {pipeline.stats.timings[-1]['frame']:.0f} ms"
                  f" | net EPE {m['epe']:.2f} px bad-3 {m['bad3']:.1f}% | SGBM EPE "
                  f"{m_sgbm['epe']:.2f} px bad-3 {m_sgbm['bad3']:.1f}% ({ms:.0f} ms)")
            if not picture:
                picture.append(demo_picture(output.left, output.sparse,
                                            output.result.disparity, gt, sgbm,
                                            output.result.depth, output.result.confidence))

        stats = run(source, pipeline, on_output=on_output)
    cv2.imwrite(str(out / "demo.png"), picture[0])
    lat = summarise(stats.timings)
    print(f"summary over {stats.frames} frames, latency median / p95 ms:")
    print("  " + format_latency(lat))
    net_epe = stats.metrics.mean("epe")
    net_bad3 = stats.metrics.mean("bad3")
    sgbm_epe = np.mean([r["epe"] for r in sgbm_rows])
    sgbm_bad3 = np.mean([r["bad3"] for r in sgbm_rows])
    sgbm_ms = float(np.median([r["ms"] for r in sgbm_rows]))
    print(f"  network ({engine.precision}) EPE {net_epe:.2f} px, bad-3 {net_bad3:.1f}%, "
          f"engine {lat['engine']['median']:.0f} ms")
    print(f"  OpenCV SGBM     EPE {sgbm_epe:.2f} px, bad-3 {sgbm_bad3:.1f}%, "
          f"{sgbm_ms:.0f} ms (same pairs, same run)")
    if stats.errors or stats.drops:
        print(f"  errors {dict(stats.errors)}, drops {stats.drops}")
    print(f"wrote {out / 'demo.mcap'} ({len(logger.files)} file, {logger.messages} messages) "
          f"and {out / 'demo.png'}")
    return 0
