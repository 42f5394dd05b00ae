"""How `edge-depth adapt` judges bundles on its check frames without ground truth
(`edge.selfcheck`), decides, and reports (markdown, and a picture of check frames)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from edge_depth import selfcheck
from edge_depth.compare import accuracy
from edge_depth.runtime.engine import Engine
from edge_depth.tools.adapt_frames import Frame


def check(engines: dict[str, Engine], frames: list[Frame], seed: int = 0
          ) -> tuple[dict[str, dict], list[dict], dict]:
    """Each engine on the check frames: (means per engine, rows per frame, disparities of a
    few frames for the picture). Photometric error is averaged over the pixels visible under
    every engine's estimate, so no engine gains by calling its mistakes occlusions."""
    rows, shown = [], {}
    show = set(np.linspace(0, len(frames) - 1, min(3, len(frames))).round().astype(int))
    for i, frame in enumerate(frames):
        sparse_l, sparse_r = frame.sparse("left"), frame.sparse("right")
        fed, held = selfcheck.split_points(sparse_l > 0, seed + i)
        outputs = {}
        for name, engine in engines.items():
            d = engine.infer(frame.left, frame.right, sparse_l).disparity
            d_right = engine.infer(np.ascontiguousarray(frame.right[:, ::-1]),
                                   np.ascontiguousarray(frame.left[:, ::-1]),
                                   np.ascontiguousarray(sparse_r[:, ::-1])).disparity[:, ::-1]
            d_half = engine.infer(frame.left, frame.right, np.where(fed, sparse_l, 0)
                                  ).disparity if held.any() else None
            outputs[name] = (d, d_right, d_half)
        seen = np.logical_and.reduce([selfcheck.visible(d, dr) for d, dr, _ in outputs.values()])
        row = dict(recording=Path(frame.recording).name, stamp_ns=frame.stamp_ns)
        for name, (d, d_right, d_half) in outputs.items():
            photo = selfcheck.photometric_error(frame.left, frame.right, d)
            m = dict(photometric=float(photo[seen].mean()) if seen.any() else float("nan"),
                     lr_inconsistent_pct=100 * selfcheck.lr_inconsistent_share(d, d_right),
                     held_out_px=selfcheck.held_out_error(d_half, sparse_l, held)
                     if d_half is not None else float("nan"))
            if frame.gt is not None:
                error_sum, bad, pixels = accuracy(d, frame.gt)
                m.update(epe=error_sum / max(pixels, 1), bad3=100 * bad / max(pixels, 1))
            row[name] = m
        rows.append(row)
        if i in show:
            shown[i] = (frame, {name: outputs[name][0] for name in ("before", "after")
                                if name in outputs})
    means = {}
    for name in engines:
        keys = sorted({k for r in rows for k in r[name]})
        means[name] = {k: float(np.nanmean([r[name].get(k, np.nan) for r in rows]))
                       if any(np.isfinite(r[name].get(k, np.nan)) for r in rows)
                       else float("nan") for k in keys}
    return means, rows, shown


def is_better(old: dict, new: dict, photometric_only: bool = False) -> tuple[bool, str]:
    """The decision without ground truth: lower photometric error and lower held-out LiDAR
    error. A measure that is NaN or missing never passes: without held-out LiDAR on the check
    frames the decision fails unless `photometric_only` (the user's --photometric-only) says
    to decide on the photometric error alone."""
    def value(bundle: dict, key: str) -> float:
        v = bundle.get(key)
        return float(v) if v is not None else float("nan")

    photo_old, photo_new = value(old, "photometric"), value(new, "photometric")
    held_old, held_new = value(old, "held_out_px"), value(new, "held_out_px")
    why = (f"photometric {photo_old:.4f} -> {photo_new:.4f}, held-out LiDAR {held_old:.3f} -> "
           f"{held_new:.3f} px")
    if not (np.isfinite(photo_old) and np.isfinite(photo_new)):
        return False, why + " (no photometric measure: nothing says it is better)"
    photo = photo_new < photo_old
    if np.isfinite(held_old) and np.isfinite(held_new):
        return photo and held_new < held_old, why
    if photometric_only:
        return photo, why + " (decided on the photometric error alone: --photometric-only)"
    return False, why + (" (no held-out LiDAR error on the check frames: give "
                         "--photometric-only to decide on the photometric error alone)")


def decide(means: dict[str, dict], photometric_only: bool = False) -> tuple[bool, str]:
    """Whether the adapted bundle ("after") is written: better than the old one as it ran
    ("before") by `is_better`, and, where the old weights were also run at the camera's size
    ("unadapted"), better than those too: they are the user's other choice (the old bundle
    with scale = "native"). With the reason, the held-out change split into what the
    resolution and what the adaptation did."""
    better, why = is_better(means["before"], means["after"], photometric_only)
    if "unadapted" not in means:
        return better, why
    held = [means[k].get("held_out_px", float("nan")) for k in ("before", "unadapted", "after")]
    why += (f"; held-out LiDAR from the camera's resolution {held[0]:.3f} -> {held[1]:.3f} px, "
            f"from adaptation {held[1]:.3f} -> {held[2]:.3f} px")
    if better and not is_better(means["unadapted"], means["after"], photometric_only)[0]:
        return False, why + ("; not better than the old weights at the camera's size: run the "
                             "old bundle with [engine] scale = \"native\" instead")
    return better, why


def colour(disparity: np.ndarray, top: float) -> np.ndarray:
    d = np.clip(np.nan_to_num(disparity) / max(top, 1e-6) * 255, 0, 255).astype(np.uint8)
    return cv2.applyColorMap(d, cv2.COLORMAP_TURBO)


TILE_WIDTH = 640  # px: wider cameras are scaled down in the report picture


def picture(shown: dict, path: Path) -> None:
    """Rows of check frames: left | before | after (| |error| before | after, with GT)."""
    rows = []
    for frame, outputs in shown.values():
        top = float(np.percentile(frame.gt[frame.gt > 0], 99)) if frame.gt is not None \
            and (frame.gt > 0).any() else float(np.nanpercentile(outputs["before"], 99))
        tiles = [("left", cv2.cvtColor(frame.left, cv2.COLOR_GRAY2BGR))]
        tiles += [(name, colour(d, top)) for name, d in outputs.items()]
        if frame.gt is not None:
            for name, d in outputs.items():
                err = np.where(frame.gt > 0, np.abs(np.nan_to_num(d) - frame.gt), 0)
                tiles.append((f"|error| {name}", colour(err, 5.0)))
        scale = min(1.0, TILE_WIDTH / frame.left.shape[1])  # a wide camera's row stays legible
        row = []
        for label, tile in tiles:
            if scale < 1.0:
                tile = cv2.resize(tile, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            cv2.putText(tile, label, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2)
            row.append(tile)
        rows.append(np.hstack(row))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
    cv2.imwrite(str(path), np.vstack(rows))


def format_report(report: dict) -> str:
    names = list(report["check"])
    keys = [k for k in ("photometric", "held_out_px", "lr_inconsistent_pct", "epe", "bad3")
            if k in report["check"]["before"]]
    lines = [f"# edge-depth adapt: {', '.join(report['recordings'])}", "",
             f"{report['frames']['adapt']} adapt frames, {report['frames']['check']} check "
             + ("frames (test-time adaptation: the same frames, their GT never used); "
                if report["test_time"] else
                f"frames (the last {report['check_share']:.0%} of each recording, never "
                "trained on); ")
             + f"fine-tuning: {report['training']['steps']} steps in "
             f"{report['training']['minutes']} min ({report['training']['mode']}).", "",
             "| on the check frames | " + " | ".join(keys) + " |",
             "|---|" + "---|" * len(keys)]
    for name in names:
        source = report["bundles"].get(name, "the starting weights at the camera size")
        lines.append(f"| {name} ({source}) | "
                     + " | ".join(f"{report['check'][name][k]:.4f}" for k in keys) + " |")
    lines += ["", f"**{report['verdict']}** ({report['why']})", ""]
    if "unadapted" in report["check"]:
        lines += ["The old bundle ran the camera scaled to its own size; `unadapted` is the "
                  "starting weights exported at the camera's size, so after − unadapted is "
                  "what adaptation itself changed.", ""]
    return "\n".join(lines)
